"""The terms of the active sonar equation as plain numbers: the formulas and defaults of
`mitsonar.acoustics.levels`, under the sonar equation's name (the receiver, below this room,
uses them from there). The levels of a `Scan` are `mitsonar.sonar_equation.scan_levels`."""
from mitsonar.acoustics.levels import (CALIBRATION_DB, DEFAULT_NOISE_LEVEL, DEFAULT_RECEIVER_SENSITIVITY,  # noqa: F401
                                       DEFAULT_SOURCE_LEVEL, SOURCE_LEVELS, ambient_noise_level, echo_level,
                                       noise_band_level, phong_sphere_cross_section, pulse_boxcar,
                                       source_level_error, transmission_loss, two_way_transmission_loss)
from mitsonar.scan.migrations import CALIBRATION_UNTIL, migrate_settings, rename_settings  # noqa: F401
