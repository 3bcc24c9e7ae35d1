"""Acoustics of sea water and the seabed in physical units (NumPy, no Mitsuba).

* :class:`Water`, the water as one value (temperature, salinity, pH, surface, latitude, the
  equations' names; the sensor's water parameters), and :data:`SOUND_SPEED`, the nominal sound
  speed every ``sound_speed`` default takes (`mitsonar.acoustics.water`);
* :func:`sound_speed` (Mackenzie 1981, UNESCO/Chen-Millero, Del Grosso by ``model=``) and
  :func:`absorption` (Francois and Garrison 1982, Ainslie and McColm 1998, fresh water);
* :func:`reflection_coefficient` and :func:`critical_angle` of a fluid-fluid interface;
* seabed backscattering strength: :func:`lambert` and :func:`apl_uw_backscatter` (APL-UW TR 9407),
  with the handbook's sediments in :data:`SEDIMENTS` and :func:`bistatic_mean_grazing`;
* material presets (:data:`MATERIALS`, :func:`material`);
* sound-speed profiles (:class:`SoundSpeedProfile`): refracted rays, travel times and their inverse
  (`SoundSpeedProfile.trace`, `SoundSpeedProfile.locate`; `mitsonar.products.raydiagram` draws them);
* eigenrays, arrivals and one-way transmission loss (:func:`eigenrays`, :func:`arrivals`,
  :func:`transmission_loss`, :func:`transmission_loss_field`; `mitsonar.acoustics.propagation`),
  and Bellhop's files to check them with (`mitsonar.acoustics.bellhop`).

Sound speed and absorption outside their equation's range warn once (``strict=True`` refuses);
the other functions refuse an input outside the range their source was fitted over, before any
work, with one line naming the field and the range. Angles are grazing angles in radians.
"""
from mitsonar.acoustics.interface import critical_angle, loss_parameter, reflection_coefficient
from mitsonar.acoustics.materials import MATERIALS, Material, material
from mitsonar.acoustics.profile import ProfileError, RayPath, SoundSpeedProfile
from mitsonar.acoustics.propagation import (ARRIVAL_DTYPE, FluidBottom, arrivals, eigenrays, transmission_loss,
                                            transmission_loss_field)
from mitsonar.acoustics.seabed import (APL_UW_FREQUENCY_RANGE, SEDIMENTS, Sediment, apl_uw_backscatter, bistatic_mean_grazing,
                     lambert, sediment)
from mitsonar.acoustics.seawater import (FRANCOIS_GARRISON_RANGE, MACKENZIE_RANGE, OutOfRangeWarning, absorption,
                                         ainslie_mccolm, depth_to_pressure, sound_speed)
from mitsonar.acoustics.water import SOUND_SPEED, Water

__all__ = ["ARRIVAL_DTYPE", "FluidBottom", "arrivals", "eigenrays", "transmission_loss", "transmission_loss_field",
           "APL_UW_FREQUENCY_RANGE", "FRANCOIS_GARRISON_RANGE", "MACKENZIE_RANGE", "MATERIALS", "Material",
           "OutOfRangeWarning", "ProfileError", "RayPath", "ainslie_mccolm", "depth_to_pressure", "SEDIMENTS", "Sediment", "SoundSpeedProfile", "absorption",
           "apl_uw_backscatter", "bistatic_mean_grazing", "critical_angle", "lambert", "loss_parameter", "material",
           "reflection_coefficient", "sediment", "sound_speed", "SOUND_SPEED", "Water"]
