"""Strip-map synthetic aperture sonar (SAS) from the coherent echoes.

`StripMap` is the configuration (a side-looking array of ``N`` receivers of length ``D``, a
wideband transmit element, the ping rate; the DPCA condition and the closed-form resolutions);
`mitsonar.render_echoes` with its ``sensor_xml`` head, its ``elements`` and its ``track`` renders
the element echoes along the trajectory (the platform's motion within and between pings);
`form_image` focuses them by time-domain backprojection on a ground-range `Grid` (Dr.Jit kernels,
bounded memory, the CUDA variants on a GPU), with the navigation taken from a second trajectory so
navigation errors defocus the image; `omega_k` is the wavenumber-domain processor for a straight
track (FFTs instead of pixels x pairs); `micronavigation` estimates the sway from the redundant
phase centres (DPCA) and gives the corrected navigation; `psf` measures the point-spread function (widths, PSLR,
ISLR); `write_sas_geotiff` writes an image as GeoTIFF in the survey's CRS; `plot_psf` draws the
point-spread function. Tutorial: docs/tutorials/sas.rst.
"""
from __future__ import annotations

from mitsonar.sas.backprojection import Grid, SASImage, compressed, form_image, row_geometry
from mitsonar.sas.config import WINDOW_FACTORS, SASWarning, StripMap
from mitsonar.sas.micronavigation import micronavigation
from mitsonar.sas.omega_k import omega_k
from mitsonar.sas.plots import plot_psf
from mitsonar.sas.products import write_sas_geotiff
from mitsonar.sas.quality import psf

__all__ = ["StripMap", "SASWarning", "WINDOW_FACTORS", "Grid", "SASImage", "form_image", "compressed",
           "row_geometry", "psf", "micronavigation", "write_sas_geotiff", "plot_psf", "omega_k"]
