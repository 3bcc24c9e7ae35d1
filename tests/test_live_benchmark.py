"""benchmarks/live.py's A/B mode without serving anything: the arguments, the sides' capabilities
read from ``mitsonar live --help``, the A/B order and the figures and ratios from given records
(no timing)."""
import sys

import pytest
from conftest import script



@pytest.fixture(scope="module")
def live():
    return script("benchmarks/live.py")


OLD_HELP = """0.2.0
usage: mitsonar live [-h] [--head {micron,ping360}] [--port-url URL] [--ping-rate HZ]
                     [--records FILE.csv|FILE.jsonl] [--sensor ID|INDEX] [--pose-url URL] SCENE.xml
"""


def rows(paths, latency, error, budget=50.0):
    return [{"paths": str(p), "latency_ms": str(t), "error": str(e), "budget_ms": str(budget), "render_ms": "1"}
            for p, t, e in zip(paths, latency, error)]


def test_a_side_lacking_a_head_leaves_its_case_to_the_other(live):
    old = live.parse_live_help("B", "/old/python", OLD_HELP)
    assert old.version == "0.2.0" and old.heads == {"micron", "ping360"}
    assert old.lacks(live.CASES["micron"][1]) == []
    assert old.lacks(live.CASES["oculus512"][1]) == ["--head oculus", "--status-port"]
    new = live.Side("A", sys.executable, ("micron", "ping360", "oculus"),
                    {"--head", "--sensor", "--port-url", "--status-port", "--pose-url", "--records", "--ping-rate"})
    plan, skipped = live.ab_plan(["micron", "oculus512"], 2, (new, old))
    assert [(c, s.label) for c, s in plan] == [("micron", "A"), ("micron", "B"), ("micron", "A"), ("micron", "B"),
                                               ("oculus512", "A"), ("oculus512", "A")]
    assert skipped == {"oculus512": {"B": "its mitsonar live has no --head oculus, --status-port"}}


def test_ratios_are_a_over_b_of_the_pooled_records(live):
    a = [live.Run("micron", rows([4000, 6000], [100, 110], [0.01, 0.03]), 1.0, "a0", {}),
         live.Run("micron", rows([6000, 6000], [100, 120], [0.01, 0.01]), 3.0, "a1", {})]
    b = [live.Run("micron", rows([2000, 2000, 2000, 2000], [100, 100, 100, 100], [0.02] * 4), 2.0, "b0", {})]
    out = live.ab_summary("micron", a, b)
    assert out["A"]["pings"] == 4 and out["A"]["seconds"] == 4.0 and out["A"]["pings_per_s"] == 1.0
    assert out["A"]["paths_p50"] == 6000.0 and out["B"]["paths_p50"] == 2000.0 and out["A"]["paths_mean"] == 5500.0
    assert out["A"]["latency_ms"]["p50"] == 105.0 and out["A"]["summaries"] == ["a0", "a1"]
    assert out["ratios_a_over_b"] == {"paths_p50": 3.0, "paths_mean": 2.75, "latency_ms_p50": 1.05,
                                      "latency_ms_p95": pytest.approx(118.5 / 100, abs=1e-3),
                                      "pings_per_s": 0.5, "budget_ms_p50": 1.0}


def test_a_case_served_by_one_side_has_no_ratios(live):
    a = [live.Run("oculus512", rows([100], [90], [0.1]), 1.0, "a", {})]
    out = live.ab_summary("oculus512", a, [], {"B": "its mitsonar live has no --head oculus"})
    assert out["B"] is None and "ratios_a_over_b" not in out and out["skipped"]["B"].endswith("--head oculus")


@pytest.mark.parametrize("argv, message", [
    (["--cases", "micron,sidescan"], "--cases: unknown case(s) sidescan; allowed: micron, ping360, multibeam256, oculus512"),
    (["--rounds", "0"], "--rounds: 0; allowed: an integer >= 1"),
    (["--baseline-python", "/nonexistent/python"], "--baseline-python: /nonexistent/python is not an executable file"),
    (["--baseline-python", sys.executable, "--soak"], "--baseline-python: not with --soak"),
])
def test_bad_arguments_are_refused_in_one_line_before_any_work(live, argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        live.parse_args(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert message in err


def test_live_bound_puts_each_target_against_the_paths_its_rays_allow(tmp_path, capsys):
    """benchmarks/live_bound.py on a given A/B JSON: per case the bound is the budget's p50 times
    the live headroom times the bare loop's paths per second (per row), the target the case's
    factor times B's paths p50; its ratio above 1 means rays faster than the bare loop. Measured
    here are only the rays (a few seconds); the arithmetic is checked, not the speed."""
    import json

    bound = script("benchmarks/live_bound.py")
    ab = {"cases": [{"case": c, "A": {"budget_ms_p50": 40.0, "paths_p50": 4096},
                     "B": {"paths_p50": 1024}} for c in ("micron", "multibeam256")]}
    path = tmp_path / "ab.json"
    path.write_text(json.dumps(ab))
    bound.main(["--ab", str(path), "--repeats", "1"])
    out = json.loads(capsys.readouterr().out)
    for case, rows in (("micron", 1), ("multibeam256", 256)):
        c = out["cases"][case]
        assert c["rows"] == rows and 1.0 <= c["segments_per_path"] <= 2 * 3 + 1   # max_depth 3: a hit and a test each
        assert c["bound_paths_per_s"] == pytest.approx(c["bare_loop_segments_per_s"] / c["segments_per_path"], rel=1e-3)
        assert c["bound_paths_per_ping"] == pytest.approx(0.8 * 0.040 * c["bound_paths_per_s"] / rows, rel=1e-3)
        assert c["target_paths"] == bound.TARGETS[case] * 1024
        assert c["target_over_bound"] == pytest.approx(c["target_paths"] / c["bound_paths_per_ping"], rel=1e-2)
    assert "budget_ms_p50" not in out["cases"]["ping360"]     # not in the A/B: the rays alone
    with pytest.raises(SystemExit):
        bound.main(["--ab", str(tmp_path / "missing.json")])
    assert "--ab:" in capsys.readouterr().err
