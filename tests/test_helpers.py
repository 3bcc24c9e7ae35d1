"""One of each small helper: an exception's first line (`mitsonar._checks.first_line`), the output
file and folder checks (`mitsonar._files`), "one scan or a list" (`mitsonar.scan.as_scans`); and no
copies of them left in mitsonar (hilbertmap keeps its own: it must not import mitsonar)."""
import ast
import os
import pathlib

import numpy as np
import pytest

from mitsonar._checks import first_line
from mitsonar._files import check_output_file, check_output_folder, make_output_folder
from mitsonar.scan import Scan, as_scans

ROOT = pathlib.Path(__file__).resolve().parents[1]


class Refused(ValueError):
    pass


def test_first_line():
    assert first_line(ValueError("  bad value\nmore detail\n")) == "bad value"
    assert first_line(KeyError()) == "KeyError" and first_line(ValueError(" \n "), None) is None
    wrapped = RuntimeError("Traceback (most recent call last):\n  File \"x.py\", line 1\nValueError: the reason\n")
    assert first_line(wrapped) == "Traceback (most recent call last):"
    assert first_line(wrapped, traceback_reason=True) == "ValueError: the reason"


def test_output_file_checks_in_order(tmp_path, monkeypatch):
    (tmp_path / "d.exr").mkdir()
    (tmp_path / "old.exr").write_bytes(b"x")
    cases = [(tmp_path / "d.exr", f"{tmp_path / 'd.exr'}: is a directory; give a file name"),
             (tmp_path / "a.txt", f"{tmp_path / 'a.txt'}: unknown extension '.txt'; use .exr or .npz"),
             (tmp_path / "noext", f"{tmp_path / 'noext'}: unknown extension '(none)'; use .exr or .npz"),
             (tmp_path / "old.exr", f"{tmp_path / 'old.exr'}: exists; refusing to overwrite it (use --force)"),
             (tmp_path / "no" / "a.npz", f"{tmp_path / 'no' / 'a.npz'}: folder {tmp_path / 'no'} does not exist")]
    for path, message in cases:
        with pytest.raises(Refused) as info:
            check_output_file(path, Refused, extensions=(".exr", ".npz"), force=False)
        assert str(info.value) == message
    assert check_output_file(tmp_path / "A.EXR", Refused, extensions=(".exr",)) == str(tmp_path / "A.EXR")
    assert check_output_file(tmp_path / "old.exr", Refused, force=True) == str(tmp_path / "old.exr")
    # a folder the caller is about to make; a command's own words
    assert check_output_file(tmp_path / "new" / "b.mcap", Refused, folder_may_be=tmp_path / "new")
    with pytest.raises(Refused, match=r"^out 'x.txt' is not a file of \.png, \.pdf$"):
        check_output_file("x.txt", Refused, extensions=(".png", ".pdf"),
                          words={"extension": "out {path!r} is not a file of {allowed_list}"})
    real = os.access   # root writes anywhere: let the check see what a user would
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(tmp_path) else real(p, mode))
    with pytest.raises(Refused, match=rf"folder {tmp_path} is not writable"):
        check_output_file(tmp_path / "c.npz", Refused)
    with pytest.raises(Refused, match=rf"^-o '{tmp_path}': the output folder is not writable$"):
        make_output_folder(str(tmp_path), Refused)
    assert sorted(os.listdir(tmp_path)) == ["d.exr", "old.exr"]          # the checks create nothing


def test_output_folder_checks(tmp_path, monkeypatch):
    f = tmp_path / "f"
    f.write_bytes(b"")
    with pytest.raises(Refused, match=rf"^-o '{f}' is a file, not a folder$"):
        check_output_folder(str(f), Refused, writable=True)
    with pytest.raises(Refused, match=rf"^-o '{f / 'sub'}': cannot create the output folder \('{f}' is a file, not a folder\)$"):
        check_output_folder(str(f / "sub"), Refused, writable=True)
    check_output_folder(str(f / "sub"), Refused)           # without writable: only the folder itself
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(tmp_path) else real(p, mode))
    with pytest.raises(Refused, match=rf"\('{tmp_path}': permission denied\)$"):
        check_output_folder(str(tmp_path / "new" / "x"), Refused, writable=True)
    with pytest.raises(Refused, match=r": cannot write in the output folder \(permission denied\)$"):
        check_output_folder(str(tmp_path), Refused, writable=True)
    assert os.listdir(tmp_path) == ["f"]


def test_one_scan_or_a_list():
    s = Scan(intensity=np.zeros((1, 2), np.float32), data=np.zeros((1, 2), np.uint8), ranges=[0.5, 1.5],
             bearings=[0.0], poses=np.eye(4)[None], range_min=0.0, range_max=2.0)

    class Poses:
        poses = None

    assert as_scans(s) == [s] and as_scans([s, s]) == [s, s] and as_scans(iter([s])) == [s]
    p = Poses()
    assert as_scans(p) == [p] and as_scans(()) == []


def _calls(tree, pick):
    return [node for node in ast.walk(tree) if pick(node)]


def _first_line_copy(node):
    """``<...>.splitlines()[0]`` of ``str(<name>)``: a first line of an exception, written again."""
    return (isinstance(node, ast.Subscript) and isinstance(node.value, ast.Call)
            and isinstance(node.value.func, ast.Attribute) and node.value.func.attr == "splitlines"
            and "str(" in ast.unparse(node.value.func.value))


def _scans_test(node):
    """``[scans] if hasattr(scans, ...) else list(scans)``: one scan or a list, written again."""
    return (isinstance(node, ast.IfExp) and isinstance(node.test, ast.Call)
            and ast.unparse(node.test.func) in ("hasattr", "isinstance") and ast.unparse(node.body).startswith("[scan"))


def _access_check(node):
    """``os.access(...)``: whether a path can be written, asked again (an output check)."""
    return isinstance(node, ast.Call) and ast.unparse(node.func) == "os.access"


@pytest.mark.parametrize("pick, home", [(_first_line_copy, "mitsonar/_checks.py"),
                                        (_scans_test, "mitsonar/scan/model.py"),
                                        (_access_check, "mitsonar/_files.py")])
def test_mitsonar_has_one_of_each_helper(pick, home):
    """Copies are found only in their home module (hilbertmap may keep its own: it must not import
    mitsonar)."""
    allowed = {home}
    found = []
    for path in sorted((ROOT / "mitsonar").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if _calls(tree, pick) and rel not in allowed:
            found.append(rel)
    assert found == []
