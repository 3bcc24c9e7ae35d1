"""The equal-time benchmark (benchmarks/mlt_equal_time.py): what it reports is what it measured.

No timing is asserted (CPU time varies by machine): the checks are on the bookkeeping, which holds
whatever the times: the ratio is the ratio of medians of ``error x sqrt(seconds)``, each per-repeat
ratio is its pair's, the spread brackets the ratio, the errors are deterministic per seed (the
same renders twice give the same errors), the reference is cached, and bad arguments are refused
before any render.
"""
from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import script



@pytest.fixture(scope="module")
def bench():
    return script("benchmarks/mlt_equal_time.py")


def test_ratio_spread_and_errors_are_what_was_measured(bench, tmp_path, monkeypatch):
    import mitsonar  # noqa: F401

    tof = {"type": "sonar_tof", "max_depth": 3}
    out = bench.measure("hidden_target", tof, {**tof, "sampling": "independent"}, 64, 5, 256, str(tmp_path))
    a, b = out["baseline"], out["contender"]
    assert len(a["rel_l2"]) == len(b["rel_l2"]) == 5 == len(out["per_repeat_ratios"])
    assert out["ratio"] > 0 and len(out["ratio_p10_p90"]) == 2
    assert out["ratio_p10_p90"][0] <= out["ratio_p10_p90"][1]
    assert os.path.isfile(tmp_path / "hidden_target_ref_256.npz")
    # errors do not depend on the times: a second measurement (the reference from the cache)
    # gives the same baseline errors, render for render
    again = bench.measure("hidden_target", tof, {**tof, "sampling": "independent"}, 64, 5, 256, str(tmp_path))
    assert again["baseline"]["rel_l2"] == a["rel_l2"]
    assert again["reference"] == out["reference"]
    # the spread: the renders of each side are resampled on their own (they are independent); a
    # run with the same error x sqrt(time) in every repeat has no spread, times included
    ea, eb = np.full(5, 2.0), np.full(5, 1.0)
    assert bench.bootstrap_spread(ea, np.ones(5), eb, np.ones(5), np.random.default_rng(0)) == [2.0, 2.0]
    assert bench.bootstrap_spread(ea, np.full(5, 4.0), eb, np.ones(5), np.random.default_rng(0)) == [4.0, 4.0]
    lo, hi = bench.bootstrap_spread(np.arange(1.0, 6.0), np.ones(5), eb, np.ones(5), np.random.default_rng(0))
    assert 1.0 <= lo < 3.0 < hi <= 5.0


@pytest.mark.parametrize("args, message", [
    (["--repeats", "3"], "at least 5"),
    (["--scenes", "nowhere"], "scenes_xml/nowhere.xml does not exist"),
    (["--spp", "64", "--reference-spp", "64"], "reference-spp at least twice"),
    (["--set", "split"], "expected name=value"),
])
def test_bad_arguments_are_refused_before_any_render(bench, args, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        bench.main(args + ["-o", str(tmp_path)])
    assert exc.value.code != 0
    assert message in capsys.readouterr().err + str(exc.value)
    assert not os.listdir(tmp_path)
