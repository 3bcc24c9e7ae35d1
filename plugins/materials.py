"""Acoustic material presets (diffuse, specular, shininess) usable by name from XML.

Concrete follows thesis Table 2.2 (reflection coefficient per quality, CHAUDHARI / LESLIE and
CHEESMAN) with 85 % of the reflected energy specular, the middle of the 80-95 % the thesis
assumes (section 2.3.2). Calm water reflects almost everything specularly (ETTER, via the thesis).
Sand and rock are estimates in the spirit of the thesis's Fig. 2.11 (MILLER): rough, mostly diffuse.
The shininess values are educated guesses: the thesis gives none.
"""

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
