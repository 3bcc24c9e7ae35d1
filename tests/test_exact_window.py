"""The exact sums in a window of words (plugins/exact_sum.py, issue 55 "Cheaper determinism"): the
same bits as all nine words at a fraction of the memory, an add outside the window counted, the
worst case of a word at its bound, and `run_pass` learning, growing and ending its windows."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

SCENES = os.path.join(os.path.dirname(__file__), "..", "scenes_xml")


def _f32(m, e):
    """The float32 of significand ``m`` (with its implicit bit) and biased exponent ``e``:
    ``m 2^(e - 150)``, in bucket ``(e - 1) >> 5`` with shift ``(e - 1) & 31`` (the module docstring)."""
    return np.float32(np.ldexp(np.float64(m), e - 150))


def _sums(exact_sum, values, index, n, window, active=None):
    import mitsuba as mi

    hist = exact_sum.ExactBins(n, window=window)
    hist.add(mi.Float(np.asarray(values, np.float32)), mi.UInt32(np.asarray(index, np.uint32)),
             True if active is None else mi.Bool(active))
    return hist


def _edge_values():
    """Values at the edges of every bucket, both signs, whose float64 sum depends on the order."""
    vals = []
    for k in range(8):
        for s in (0, 8, 9, 31):                  # s >= 9: the integer spills into word k + 1
            e = 32 * k + s + 1
            if 1 <= e <= 254:
                for m in (1 << 23, (1 << 24) - 1, (1 << 23) + 1):
                    vals += [_f32(m, e), -_f32(m, e)]
    vals += [np.float32(1e30), np.float32(1.0), np.float32(-1e30), np.float32(3e-38), np.float32(7e-3)]
    return np.array(vals, np.float32)


def test_a_window_of_the_words_reached_gives_the_nine_word_bits_at_every_edge(mitsonar_mod):
    """Each bin gets values of a few neighbouring buckets at their edges (shift 0, 8 | 9, 31 and
    significands 2^23, 2^24 - 1) and both signs, whose float64 sum in two orders differs; in the
    window of exactly the words they reach, the kept words are the nine-word integers, no add is
    counted, and the totals are the nine-word totals bit for bit."""
    from mitsonar.plugins.integrators.paths import exact_sum

    rng = np.random.default_rng(55)
    edge = _edge_values()
    b = ((edge.view(np.uint32) >> 23) & 0xFF).astype(int) - 1
    bucket, shift = b >> 5, b & 31
    order_dependent = 0
    for lo, hi in [(0, 1), (1, 3), (2, 4), (3, 5), (5, 8), (0, 4), (6, 7), (4, 4), (0, 8)]:
        # buckets lo .. hi - 1 (their high integers reach word hi at most) and bucket hi's values
        # shifted 8 or less (nothing above word hi)
        pick = edge[(bucket >= lo) & ((bucket < hi) | ((bucket == hi) & (shift <= 8)))]
        n = 7
        values = np.concatenate([rng.permutation(np.repeat(pick, 3)) for _ in range(4)])
        index = rng.integers(0, n, values.size)
        nine = _sums(exact_sum, values, index, n, None)
        win = _sums(exact_sum, values, index, n, (lo, hi))
        reached = nine.words.numpy().reshape(exact_sum.STRIDE, n)[:exact_sum.WORDS]
        used = [k for k in range(exact_sum.WORDS) if reached[k].any()]
        assert min(used) == lo and max(used) == min(hi, exact_sum.WORDS - 1), (lo, hi, used)   # its edges
        assert win.missed() == 0
        kept = win.words.numpy()
        np.testing.assert_array_equal(kept[:-1].reshape(hi - lo + 1, n), reached[lo:hi + 1])
        assert win.numpy().tobytes() == nine.numpy().tobytes(), (lo, hi)
        assert win.bytes_per_bin() == 8 * (hi - lo + 1) + 8 / n
        for i in range(n):
            sel = values[index == i].astype(np.float64)
            order_dependent += float(np.sum(sel)) != float(np.sum(sel[::-1])) or sum(sel) != sum(sel[::-1])
    assert order_dependent > 0, "no bin whose float64 sum depends on the order: the data tests nothing"


def test_an_add_that_puts_a_nonzero_integer_outside_the_window_is_counted(mitsonar_mod):
    """Window (2, 4): counted are a value of bucket 1 (its low integer in word 1), a value of
    bucket 4 shifted 9 or more (its high integer in word 5), one of bucket 5 and non-finite values; not counted,
    and summed exactly, a value of bucket 4 shifted 8 (its high integer is 0), one of bucket 1
    whose low 32 bits are 0 (all of it in word 2), zeros, subnormals and inactive lanes."""
    import drjit as dr

    from mitsonar.plugins.integrators.paths import exact_sum

    out = [_f32((1 << 23) + 3, 32 * 1 + 5 + 1),          # bucket 1, low integer != 0: word 1
           -_f32((1 << 24) - 1, 32 * 4 + 9 + 1),         # bucket 4, shift 9: word 5
           _f32(1 << 23, 32 * 4 + 31 + 1),               # bucket 4, shift 31: word 5
           _f32((1 << 23) + 1, 32 * 5 + 1),              # bucket 5, shift 0: word 5 alone
           np.float32(np.inf), np.float32(np.nan)]
    inside = [_f32((1 << 24) - 1, 32 * 4 + 8 + 1),        # bucket 4, shift 8: word 4 alone
              _f32(1 << 23, 32 * 1 + 9 + 1),             # bucket 1, 2^32 exactly: word 2 alone
              _f32((1 << 23) + 7, 32 * 3 + 20 + 1),      # words 3 and 4
              np.float32(0.0), np.float32(-0.0), np.float32(1e-40)]
    values = np.array(out + inside + [out[0]], np.float32)
    active = np.ones(values.size, bool)
    active[-1] = False
    index = np.arange(values.size) % 3
    win = _sums(exact_sum, values, index, 3, (2, 4), active)
    assert win.missed() == len(out)
    # what stayed inside is exactly the nine-word sums of the values inside
    keep = np.array(inside, np.float32)
    ref = _sums(exact_sum, keep, index[len(out):len(out) + len(inside)], 3, None)
    win_in = _sums(exact_sum, keep, index[len(out):len(out) + len(inside)], 3, (2, 4))
    assert win_in.missed() == 0 and win_in.numpy().tobytes() == ref.numpy().tobytes()
    with pytest.raises(ValueError, match=r"ExactBins window: \(3, 9\); allowed"):
        exact_sum.ExactBins(3, window=(3, 9))
    with pytest.raises(ValueError, match="one pass"):
        exact_sum.ExactBins(3, window=(2, 4)).reserve(1)
    assert dr.width(exact_sum.ExactBins(3, window=(2, 4)).words) == 3 * 3 + 1


def test_the_largest_integers_into_one_word_stay_exact_up_to_the_bound(mitsonar_mod):
    """The worst case of a word: every add puts the largest integer a word can get from one add
    (2^32 - 256, significand 2^24 - 1 shifted 8, and 2^23 - 1 into the word above from shift 31)
    into one bin, 2^22 times (a pass's lanes), both signs: the windowed words are those integers
    times the count exactly (past 2^53, where a float64 sum would round) and the totals the nine
    words' bits. The bound: an add puts less than 2^32 into any word, a word takes `MAX_ADDS` adds,
    so |word| < 2^62 < 2^63 (no wrap), and a pass adds at most `MAX_LANES_PER_PASS` x 64 bounces."""
    import mitsuba as mi

    from mitsonar.plugins.integrators import sonar_tof
    from mitsonar.plugins.integrators.paths import exact_sum

    assert exact_sum.MAX_ADDS * (1 << 32) < (1 << 63)
    assert sonar_tof.MAX_LANES_PER_PASS * 64 <= exact_sum.MAX_ADDS
    count = 1 << 22
    top = _f32((1 << 24) - 1, 32 * 3 + 8 + 1)           # 2^32 - 256 into word 3
    spill = _f32((1 << 24) - 1, 32 * 3 + 31 + 1)        # 2^31 into word 3, 2^23 - 1 into word 4
    for sign in (1, -1):
        index = mi.UInt32(np.zeros(count, np.uint32))
        for v in (top, spill):
            values = mi.Float(np.full(count, sign * v, np.float32))
            nine = exact_sum.ExactBins(2)
            nine.add(values, index)
            win = exact_sum.ExactBins(2, window=(3, 4))
            win.add(values, index)
            assert win.missed() == 0
            words = win.words.numpy()
            m = (1 << 24) - 1
            wide = m << (8 if v == top else 31)
            assert int(words[0]) == sign * count * (wide & 0xFFFFFFFF)
            assert int(words[2]) == sign * count * (wide >> 32)
            assert abs(int(words[0])) > (1 << 53 if v == top else 1 << 52)   # float64 would round
            assert win.numpy().tobytes() == nine.numpy().tobytes()
            assert nine.numpy()[0] == sign * count * float(v)


class _Owner:
    pass


def _pass_of(exact_sum, owner, values, n, calls):
    """`run_pass` of a pass adding ``values`` (bin i gets ``values[i::n]``), counting its calls."""
    import mitsuba as mi

    values = np.asarray(values, np.float32)

    def call(learning):
        assert learning == (exact_sum.window_of(owner) == exact_sum.ALL)
        calls.append(exact_sum.window_of(owner))
        hist = exact_sum.ExactBins(n, window=exact_sum.window_of(owner))
        hist.add(mi.Float(values), mi.UInt32(np.arange(values.size) % n))
        return exact_sum.pass_result(owner, hist)

    return exact_sum.run_pass(owner, call)


def _nine(values, n):
    """The sums of ``values`` (bin i gets ``values[i::n]``) in all nine words, no window."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import exact_sum

    hist = exact_sum.ExactBins(n)
    hist.add(mi.Float(np.asarray(values, np.float32)), mi.UInt32(np.arange(len(values)) % n))
    return hist.numpy()


def test_run_pass_grows_its_window_on_a_miss_and_ends_it(mitsonar_mod):
    """Passes sum in `DEFAULT` (words 0-4); a pass reaching above runs again in nine words (its
    bits; traced: ``learning``) and the window grows to the highest word reached; a window that
    could not grow (integers that cancel) or a non-finite echo ends the windows (nine words and
    the NaN, as before windows)."""
    from mitsonar.plugins.integrators.paths import exact_sum

    assert exact_sum.DEFAULT == (0, 4)
    owner, calls = _Owner(), []
    # bucket 1 shift 2 (word 1), bucket 2 shift 19 (words 2, 3), bucket 3 shift 4 (word 3)
    low = [_f32((1 << 23) + 5, 32 * 1 + 3), _f32((1 << 24) - 3, 32 * 2 + 20), _f32((1 << 23) + 9, 32 * 3 + 5)]
    got = _pass_of(exact_sum, owner, low, 2, calls)
    assert calls == [exact_sum.DEFAULT] and got.tobytes() == _nine(low, 2).tobytes()
    assert exact_sum.window_of(owner) == exact_sum.DEFAULT
    # bucket 4 shift 29 (words 4, 5), bucket 5 shift 8 (word 5)
    high = low + [_f32((1 << 23) + 1, 32 * 4 + 30), _f32((1 << 24) - 1, 32 * 5 + 9)]
    calls.clear()
    got = _pass_of(exact_sum, owner, high, 2, calls)
    assert calls == [exact_sum.DEFAULT, exact_sum.ALL] and got.tobytes() == _nine(high, 2).tobytes()
    assert exact_sum.window_of(owner) == (0, 5)
    calls.clear()
    got = _pass_of(exact_sum, owner, high[::-1], 2, calls)
    assert calls == [(0, 5)] and got.tobytes() == _nine(high[::-1], 2).tobytes()
    # integers of both signs into words 7 and 8 of bin 1 that cancel, the rest below word 5: the
    # window cannot grow (nor shrink): windows end
    huge = np.float32(3e37)
    cancel = low + [huge, 0.0, -huge]                      # positions 3 and 5: bin 1
    calls.clear()
    got = _pass_of(exact_sum, owner, cancel, 2, calls)
    assert calls == [(0, 5), exact_sum.ALL] and exact_sum.window_of(owner) is None
    assert got.tobytes() == _nine(cancel, 2).tobytes()
    calls.clear()
    _pass_of(exact_sum, owner, low, 2, calls)
    assert calls == [None]
    # a non-finite echo: its bin is NaN, as with nine words, and windows end
    owner, calls = _Owner(), []
    bad = low + [np.inf]
    got = _pass_of(exact_sum, owner, bad, 2, calls)
    assert calls == [exact_sum.DEFAULT, exact_sum.ALL, None] and exact_sum.window_of(owner) is None
    assert np.isnan(got[1]) and got.tobytes() == _nine(bad, 2).tobytes()


def test_two_threads_passes_of_one_owner_run_one_after_the_other(mitsonar_mod):
    """The window is the owner's state: while one thread's pass misses and learns (its window
    ALL, then widened), another thread's pass of the same owner must not start, or it would read
    one window in its body and convert its words in another. Thread A's pass reaches word 5 and
    waits inside its call until B has been started; B's pass (words 0-4) enters its call only after
    A's pass has ended, in the widened window, and both sums are the nine-word sums."""
    import threading

    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import exact_sum

    owner, events = _Owner(), []
    low = [_f32((1 << 23) + 5, 32 * 1 + 3), _f32((1 << 24) - 3, 32 * 2 + 20)]
    high = low + [_f32((1 << 23) + 1, 32 * 4 + 30)]              # words 4 and 5
    b_started, results = threading.Event(), {}

    def run(name, values):
        values = np.asarray(values, np.float32)

        def call(learning):
            events.append((name, "enter", exact_sum.window_of(owner)))
            if name == "A" and not learning:
                assert b_started.wait(10)
                time.sleep(0.2)          # B, unlocked, would enter its call now
            hist = exact_sum.ExactBins(2, window=exact_sum.window_of(owner))
            hist.add(mi.Float(values), mi.UInt32(np.arange(values.size) % 2))
            out = exact_sum.pass_result(owner, hist)
            events.append((name, "leave"))
            return out

        results[name] = exact_sum.run_pass(owner, call)

    a = threading.Thread(target=run, args=("A", high))
    a.start()
    while not events:
        time.sleep(0.01)
    b = threading.Thread(target=run, args=("B", low))
    b.start()
    b_started.set()
    a.join(20)
    b.join(20)
    assert events == [("A", "enter", exact_sum.DEFAULT), ("A", "leave"), ("A", "enter", exact_sum.ALL),
                      ("A", "leave"), ("B", "enter", (0, 5)), ("B", "leave")]
    assert results["A"].tobytes() == _nine(high, 2).tobytes()
    assert results["B"].tobytes() == _nine(low, 2).tobytes()


@pytest.mark.parametrize("xml, props", [("box.xml", {"max_depth": 3}),
                                        ("box_fls.xml", {"max_depth": 2, "share_beams": True})])
def test_a_windowed_render_is_the_nine_word_render_bit_for_bit(mitsonar_mod, xml, props):
    """sonar_tof sums in a window of fewer words than nine; its histograms are the bytes of the
    same renders by an integrator whose windows ended (all nine words, as before)."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import exact_sum

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, xml))
    windowed = mi.load_dict({"type": "sonar_tof", **props})
    nine = mi.load_dict({"type": "sonar_tof", **props})
    nine._exact_lo = nine._exact_hi = -1
    for seed in (1, 2):
        a = windowed.render_histogram(scene, 0, seed=seed, spp=256)
        b = nine.render_histogram(scene, 0, seed=seed, spp=256)
        assert exact_sum.window_of(windowed) == exact_sum.DEFAULT and exact_sum.window_of(nine) is None
        assert a.sum() > 0 and a.tobytes() == b.tobytes()
