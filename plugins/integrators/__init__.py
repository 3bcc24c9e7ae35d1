"""The integrators ``sonar_tof`` (path tracing), ``sonar_mlt`` (Metropolis, with `mlt_split`) and
``sonar_bdpt`` (bidirectional), on the shared base class of `common`; the machinery of their
paths (primary samples, range bins, exact sums, guides, row allocation, refraction, gradients)
is in `paths`."""
