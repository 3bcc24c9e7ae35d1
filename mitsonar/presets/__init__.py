"""Every sonar model's published figures, each with its source, in one room: `echosounders`
(bathymetric multibeams, an altimeter), `sidescan` (towed side-scan heads, the ``sonar`` sensor's
``preset``), `oculus` (Blueprint Oculus M750d, M1200d, M3000d), `micron` (Tritech Micron),
`ping360` (Blue Robotics Ping360) and `volumetric` (3D sonars). The heads' drivers
(`mitsonar.devices`), the scene builders and the plugins take the figures from here. A leaf: it
imports NumPy and mitsonar's value checks and sonar kinds, never the renderer."""
