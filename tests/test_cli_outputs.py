"""The ``--force`` policy of every command that writes (`mitsonar.cli.common.add_output`,
`check_outputs`): the CLI's parsers are walked, every option that names something written must be
under the policy, and each one refuses an existing output without ``--force`` (one line naming the
flag and the file, "--force to overwrite", before any work: the commands' inputs here do not
exist, so any other line would mean the command had started) and accepts it with ``--force``."""
from __future__ import annotations

import argparse
import os
import re

import pytest

from mitsonar.cli.common import check_outputs
from mitsonar.cli.main import build_parser, main

#: Words that mark an option as naming something the command writes: its dest, its flag, its
#: metavar, or its help ("also write a picture", "record the same channels into this MCAP file").
WRITING_DESTS = {"output", "out", "plot", "records", "mcap", "xtf", "log", "mesh", "elevation", "save"}
WRITING_HELP = re.compile(r"\b(write|writes|save|saves)\b|\brecord\b.*\binto\b", re.IGNORECASE)
WRITING_METAVAR = re.compile(r"\bOUT\b")
#: Options whose names look like outputs but that the command reads (command, dest).
READ_ONLY = {("virtual-sonar", "log")}     # the Oculus log a virtual head serves

#: A file each output folder's command writes into it (the folder then holds an earlier run).
FOLDER_SAMPLES = {("demo", "output"): "box.exr", ("survey", "output"): "scan_00000.npz",
                  ("bathymetry", "output"): "depth.npz"}


def _subparsers():
    """Every command's parser by its words (``"render"``, ``"scene from-grid"``): nested ones too."""
    found = {}

    def walk(parser, words):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    found[" ".join((*words, name))] = sub
                    walk(sub, (*words, name))

    walk(build_parser(), ())
    return found


def _takes_a_path(action) -> bool:
    return action.nargs in (None, "?") and action.type in (None, str) and not action.choices and \
        action.const is None and not isinstance(action, (argparse._StoreTrueAction, argparse._HelpAction))


def _writes(action) -> bool:
    flags = {f.lstrip("-") for f in action.option_strings}
    return bool(action.option_strings) and _takes_a_path(action) and (
        action.dest in WRITING_DESTS or flags & WRITING_DESTS or WRITING_HELP.search(action.help or "")
        or WRITING_METAVAR.search(str(action.metavar or "")))


def _outputs():
    """(command, action) of every output under the policy that is refused when it exists."""
    return [(name, a) for name, p in _subparsers().items() for a in p.get_default("outputs_") or ()
            if a.existing is not None]


def test_every_writing_option_is_under_the_force_policy():
    """A new option that writes a file must be added with add_output (or reused=True for a folder
    the command resumes or caches into); its command must take --force."""
    seen = []
    for name, parser in _subparsers().items():
        registered = set(parser.get_default("outputs_") or ())
        for action in parser._actions:
            if _writes(action) and (name, action.dest) not in READ_ONLY:
                seen.append((name, action.dest))
                assert action in registered, (
                    f"mitsonar {name} {'/'.join(action.option_strings)} looks like an output but is not added with "
                    "mitsonar.cli.common.add_output (the --force policy)")
        if any(a.existing is not None for a in registered):
            assert any("--force" in a.option_strings for a in parser._actions), f"mitsonar {name} has no --force"
        for action in registered:          # and every registered one is found by the walk: it means something
            assert _writes(action), (name, action.dest)
    assert len(seen) >= 19, seen


def _argv(command, parser, target, path, tmp_path):
    """A command line of ``command`` with ``target`` set to ``path``: inputs that do not exist,
    other required outputs on fresh paths."""
    argv = command.split()
    for action in parser._actions:
        if action.dest == target.dest:
            argv += [action.option_strings[0], str(path)] if action.option_strings else [str(path)]
        elif not action.option_strings and action.dest != "help":
            argv.append(str(tmp_path / "missing" / f"{action.dest}.in"))
        elif action.required:
            assert action.dest in {a.dest for a in parser.get_default("outputs_") or ()}, (command, action.dest)
            argv += [action.option_strings[0], str(tmp_path / f"fresh_{action.dest}")]
    return argv


def _existing(command, action, tmp_path):
    """An existing output for ``action``: a file, or for an output folder a folder holding one of
    the files its command writes. Returns (the path given, the one line of the refusal)."""
    flag = action.option_strings[0]
    path = tmp_path / f"old_{action.dest}.out"
    path.write_bytes(b"old")
    args = argparse.Namespace(**{action.dest: str(path)}, force=False, all=False)
    if action.existing(str(path), args):
        return path, f"{flag} {path}: exists; --force to overwrite"
    path.unlink()
    sample = FOLDER_SAMPLES.get((command, action.dest))
    assert sample is not None, f"mitsonar {command} {flag}: an output folder; name a file it writes in FOLDER_SAMPLES"
    path.mkdir()
    (path / sample).write_bytes(b"old")
    return path, f"{flag} {path}: already holds {sample}; --force to overwrite"


@pytest.mark.parametrize("command, action", _outputs(), ids=lambda v: getattr(v, "dest", v))
def test_an_existing_output_is_refused_before_any_work_and_accepted_with_force(tmp_path, capsys, command, action):
    parser = _subparsers()[command]
    path, refusal = _existing(command, action, tmp_path)
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    argv = _argv(command, parser, action, path, tmp_path)
    assert main(argv) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"mitsonar: error: {refusal}"] and captured.out == ""
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before            # nothing written, nothing removed
    # the same line with --force passes the check (the command would then start: its inputs are missing)
    check_outputs(build_parser().parse_args(argv + ["--force"]))
    # and a new path passes it without --force: the refusal was for the existing output
    check_outputs(build_parser().parse_args(_argv(command, parser, action, tmp_path / "new.out", tmp_path)))


def test_the_refusal_is_raised_as_the_callers_error(tmp_path):
    (tmp_path / "a.png").write_bytes(b"")
    args = build_parser().parse_args(["plot", "s.npz", "-o", str(tmp_path / "a.png")])
    with pytest.raises(KeyError, match=r"-o .*a\.png: exists; --force to overwrite"):
        check_outputs(args, KeyError)


def test_replay_all_refuses_any_of_its_numbered_scans(tmp_path, capsys):
    """``replay -o scan.npz --all`` writes scan_000.npz, scan_001.npz, ...: any of those existing is
    refused (the count is known only once the log is read; the check needs none)."""
    (tmp_path / "scan_004.npz").write_bytes(b"old")
    argv = ["replay", str(tmp_path / "missing.bin"), "-o", str(tmp_path / "scan.npz")]
    check_outputs(build_parser().parse_args(argv))              # without --all: scan.npz, which is new
    assert main(argv + ["--all"]) == 1
    assert capsys.readouterr().err.strip() == (f"mitsonar: error: -o {tmp_path / 'scan.npz'}: already holds "
                                               f"{tmp_path / 'scan_004.npz'}; --force to overwrite")


@pytest.mark.parametrize("argv", [["dataset", "c.yaml", "-o", "{d}"], ["compare", "s.xml", "-o", "{d}"]])
def test_folders_resumed_or_cached_into_are_not_refused(tmp_path, argv):
    """dataset resumes its folder, compare reuses the reference cached in its: never refused."""
    for name in ("manifest.json", "compare.json", "reference.npz"):
        (tmp_path / name).write_bytes(b"{}")
    check_outputs(build_parser().parse_args([a.format(d=tmp_path) for a in argv]))
    assert os.path.isdir(tmp_path)


def test_live_mcap_takes_force_down_to_the_recording(tmp_path):
    """``live --mcap OLD --force``: the recording's own check lets the existing file be replaced."""
    pytest.importorskip("foxglove")
    from mitsonar.live.outputs import OutputError
    from mitsonar.live.outputs.mcapfile import check_mcap_path

    old = tmp_path / "old.mcap"
    old.write_bytes(b"keep")
    with pytest.raises(OutputError, match=r"^--mcap .*old\.mcap: exists; --force to overwrite$"):
        check_mcap_path(old)
    assert check_mcap_path(old, force=True) == str(old)
