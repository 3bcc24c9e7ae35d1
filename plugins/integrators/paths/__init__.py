"""The integrators' path machinery: primary samples (`samples`), the path's start (`emission`),
range bins and exact sums (`range_bins`, `exact_sum`), the guides toward specular echoes
(`image_guide`, `plane_guide`, `curved_mirror`), row allocation (`row_allocation`,
`frozen_pass`), shared multibeam paths (`shared_beams`, `receive_emission`), bidirectional paths
(`bdpt_paths`), refracted paths (`refraction`), gradients (`path_replay`), denormal flushing
(`denormals`)."""
