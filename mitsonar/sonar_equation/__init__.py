"""The active sonar equation in physical units: the levels of a scan (`scan_levels`), a per-scene
report (`report`) and the terms as plain numbers (`levels`, from `mitsonar.acoustics.levels`).

``EL = SL - (40 log10 r + 2 alpha r) + TS``, ``SNR = EL - (NL + 10 log10 B - DI)``; see
`mitsonar.acoustics.levels` for the conventions and `sonar_equation_report` for the table.
"""
from mitsonar.sonar_equation.levels import (CALIBRATION_DB, DEFAULT_NOISE_LEVEL, DEFAULT_RECEIVER_SENSITIVITY, DEFAULT_SOURCE_LEVEL,
                     SOURCE_LEVELS, ambient_noise_level, echo_level, migrate_settings, noise_band_level,
                     phong_sphere_cross_section, pulse_boxcar, transmission_loss,
                     two_way_transmission_loss)
from mitsonar.sonar_equation.report import plot_levels, sonar_equation_report
from mitsonar.sonar_equation.scan_levels import ScanLevels, directivity_index, scan_echo_level, scan_levels, snr

__all__ = ["CALIBRATION_DB", "DEFAULT_NOISE_LEVEL", "DEFAULT_RECEIVER_SENSITIVITY", "DEFAULT_SOURCE_LEVEL",
           "SOURCE_LEVELS", "ScanLevels", "ambient_noise_level", "directivity_index", "echo_level",
           "migrate_settings", "noise_band_level", "phong_sphere_cross_section", "plot_levels", "pulse_boxcar",
           "scan_echo_level", "scan_levels", "snr", "sonar_equation_report", "transmission_loss",
           "two_way_transmission_loss"]
