"""The example scenes, installed as the data package ``mitsonar.scenes_xml`` (see
`mitsonar.example_scene`). This file makes the folder a regular package, which editable installs
and ``importlib.resources`` find from any working directory; it holds no code."""
