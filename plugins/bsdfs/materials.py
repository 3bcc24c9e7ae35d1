"""Acoustic material presets (diffuse, specular, shininess) usable by name from XML.

Concrete follows thesis Table 2.2 (reflection coefficient per quality, CHAUDHARI / LESLIE and
CHEESMAN) with 85 % of the reflected energy specular, the middle of the 80-95 % the thesis
assumes (section 2.3.2). Calm water reflects almost everything specularly (ETTER, via the thesis).
Sand and rock are estimates in the spirit of the thesis's Fig. 2.11 (MILLER): rough, mostly diffuse.
The shininess values are educated guesses: the thesis gives none.

Seabed presets (``seabed_sand``, ``seabed_mud``, ``seabed_gravel``, ``seabed_rock``,
``seabed_clay``) follow Lambert's law for high-frequency seafloor backscatter,
``S_b(theta_g) = mu + 10 log10(sin^2 theta_g)`` (theta_g the grazing angle). A Lambertian surface of
albedo d seen by a monostatic sonar has the backscattering cross-section per unit area and solid
angle ``sigma = (d / pi) sin^2 theta_g``, so ``mu = 10 log10(d / pi)`` and ``d = pi 10^(mu / 10)``.
The Lambert parameters ``LAMBERT_MU`` are representative values, not measurements of one site,
within the ranges reported by APL-UW, "High-Frequency Ocean Environmental Acoustic Models
Handbook", Technical Report APL-UW TR 9407 (1994), seafloor backscatter section, and by
D. R. Jackson and M. D. Richardson, "High-Frequency Seafloor Acoustics", Springer (2007):
sand about -27 dB (also Mackenzie's classic Lambert value, K. V. Mackenzie, J. Acoust. Soc. Am.
33, 1498 (1961), measured on deep-sea sediment near 1 kHz), mud and clay -30 to -35 dB (mud -32,
clay -35: the finer sediment, the weaker), gravel about -20 dB, rock -13 to -17 dB (-15, the
middle). These ranges are as summarised in mitsonar's issue 19; the handbook's own tables were not
at hand to check them against, so no value here claims more than 1 dB of precision. Sediment
backscatter varies by +-5 dB or more between sites and frequencies; treat these as typical, not
exact. They are purely diffuse (``specular`` 0): the coherent forward reflection of the
water-sediment interface and the near-nadir peak are not modelled. The older ``sand`` and ``rock``
presets stay as they were (existing scenes and their measured numbers depend on them).
"""

import math

SPECULAR_FRACTION = 0.85

# Mid-points of the reflection-coefficient ranges of thesis Table 2.2.
CONCRETE_REFLECTION = {
    "concrete_very_good": 0.80,
    "concrete_good": 0.715,
    "concrete_questionable": 0.655,
    "concrete_poor": 0.55,
    "concrete_very_poor": 0.40,
}
CONCRETE_SHININESS = 30.0

PRESETS = {
    name: {"diffuse": round(r * (1 - SPECULAR_FRACTION), 6),
           "specular": round(r * SPECULAR_FRACTION, 6),
           "shininess": CONCRETE_SHININESS}
    for name, r in CONCRETE_REFLECTION.items()
}
PRESETS.update({
    "water_calm": {"diffuse": 0.0, "specular": 0.99, "shininess": 2000.0},
    "sand": {"diffuse": 0.25, "specular": 0.05, "shininess": 5.0},
    "rock": {"diffuse": 0.35, "specular": 0.15, "shininess": 10.0},
})

#: Lambert parameter mu (dB re 1 m^2 per m^2 per sr) of each seabed preset: representative values,
#: sources in the module docstring.
LAMBERT_MU = {"seabed_sand": -27.0, "seabed_mud": -32.0, "seabed_clay": -35.0,
              "seabed_gravel": -20.0, "seabed_rock": -15.0}


def lambert_albedo(mu_db: float) -> float:
    """Diffuse albedo d of a Lambertian seabed with Lambert parameter ``mu_db``: d = pi 10^(mu/10)."""
    return math.pi * 10.0 ** (mu_db / 10.0)


PRESETS.update({name: {"diffuse": round(lambert_albedo(mu), 8), "specular": 0.0, "shininess": 1.0}
                for name, mu in LAMBERT_MU.items()})
