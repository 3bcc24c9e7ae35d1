"""The example scenes ship with the package (`mitsonar.example_scene`), so the README's Python
works from any folder once mitsonar is installed, not only from the repository's root."""
import os
import re
import subprocess
import sys
from importlib import resources

import pytest

from conftest import ROOT, SCENES

README = os.path.join(ROOT, "README.md")


def python_blocks(section):
    """The ```python blocks of the README section headed ``section`` (up to the next heading)."""
    text = open(README, encoding="utf-8").read()
    start = text.index(f"\n{section}\n")
    end = re.compile(r"\n#{1,6} ").search(text, start + 1)
    body = text[start: end.start() if end else len(text)]
    return re.findall(r"```python\n(.*?)```", body, re.S)


def test_readme_quick_start_runs_from_another_folder(tmp_path):
    blocks = python_blocks("## Use from Python")
    assert len(blocks) == 2 and all("example_scene(" in b for b in blocks), blocks
    code = "\n".join(blocks) + "\nprint('shape', scan.intensity.shape, image.shape)\n"
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)  # the installed package, not the source tree
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "shape (200, 500) (200, 500, 1)" in proc.stdout, proc.stdout
    assert (tmp_path / "box.exr").is_file() and (tmp_path / "box.png").read_bytes()[:4] == b"\x89PNG"


def test_readme_python_names_only_shipped_files():
    """No snippet names a scene by a path relative to the repository, and every name it gives to
    `example_scene` exists (a renamed scene breaks this test, not the reader)."""
    import mitsonar

    text = open(README, encoding="utf-8").read()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks
    for b in blocks:
        assert "scenes_xml/" not in b, b
    names = re.findall(r"example_scene\(\"([^\"]+)\"\)", "\n".join(blocks))
    assert {"box", "hidden_target", "wreck_sidescan", "wreck_sidescan_survey.tum"} <= set(names)
    for name in names:
        assert os.path.isfile(mitsonar.example_scene(name)), name


def test_resources_find_every_scene_file_through_the_package():
    """`importlib.resources` finds the scenes as ``mitsonar.scenes_xml`` (what a wheel installs,
    package-dir mapping scenes_xml/ there), every file of the folder, and each file a scene names
    by a relative path sits next to it."""
    import mitsonar

    folder = resources.files("mitsonar.scenes_xml")
    shipped = {p.name for p in folder.iterdir() if p.is_file()}
    source = {f for f in os.listdir(SCENES) if os.path.isfile(os.path.join(SCENES, f))}
    assert source - {"__init__.py"} <= shipped
    scenes = mitsonar.example_scenes()
    assert scenes == sorted(f[:-4] for f in source if f.endswith(".xml")) and "box" in scenes
    referenced = 0
    for name in scenes:
        path = mitsonar.example_scene(name)
        assert os.path.isabs(path) and (folder / f"{name}.xml").read_bytes() == open(path, "rb").read()
        # (a regular expression: Mitsuba's parser takes comments that ElementTree refuses)
        for file in re.findall(r'name="filename"\s+value="([^"]+)"', open(path, encoding="utf-8").read()):
            referenced += 1
            assert (folder / file).is_file(), (name, file)
    assert referenced >= 3  # rocky_slope and wreck's meshes


def test_a_scene_with_a_mesh_loads_from_another_folder(tmp_path, monkeypatch, mitsonar_mod):
    monkeypatch.chdir(tmp_path)
    scene = mitsonar_mod.load_scene(mitsonar_mod.example_scene("rocky_slope"))
    assert any(s.face_count() > 1000 for s in scene.shapes())  # the seabed mesh, found by its relative path


@pytest.mark.parametrize("name", ["nope", "box.ply", "../scenes_xml/box", "", None])
def test_an_unknown_name_is_one_line_listing_the_scenes(mitsonar_mod, name):
    with pytest.raises(ValueError) as err:
        mitsonar_mod.example_scene(name)
    msg = str(err.value)
    assert "\n" not in msg and repr(name) in msg and "available: box, box_fls," in msg, msg
