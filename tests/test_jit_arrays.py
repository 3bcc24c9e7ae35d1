"""Arrays uploaded to Dr.Jit give the same kernels wherever NumPy happened to allocate them."""
import numpy as np

import pytest
from conftest import jit_kernels, on_cuda


def test_uploads_at_any_address_share_one_kernel(mitsonar_mod):
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.jit_arrays import upload

    buf = np.arange(1000, dtype=np.float32)
    hashes, results = set(), []
    for offset in range(16):  # 4-byte steps: every alignment up to 64 bytes
        values = buf[offset:offset + 900]

        def run():
            x = upload(mi.Float, values, np.float32)
            y = x * 3.0 + 1.0
            dr.eval(y)
            results.append(y.numpy())

        launched, _ = jit_kernels(run)
        hashes.update(launched)
        np.testing.assert_array_equal(results[-1], values * 3 + 1)
    assert len(hashes) == 1, f"{len(hashes)} kernels for one computation"


@pytest.mark.skipif("on_cuda()", reason="the CUDA backend copies NumPy arrays to the GPU: no kernel "
                    "is compiled for a mapped array's alignment there, so upload() has nothing to prevent")
def test_plain_numpy_uploads_do_not_share_one_kernel(mitsonar_mod):
    # What upload() is for: Dr.Jit compiles reads of mapped NumPy memory for its alignment.
    import drjit as dr
    import mitsuba as mi

    buf = np.arange(1000, dtype=np.float32)
    hashes = set()
    for offset in range(16):
        def run():
            dr.eval(mi.Float(buf[offset:offset + 900]) * 3.0 + 1.0)

        hashes.update(jit_kernels(run)[0])
    assert len(hashes) > 1


def test_one_element_is_not_baked_into_the_kernel(mitsonar_mod):
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.jit_arrays import upload

    kernels = []
    for value in (0.0, 5.0):
        def run():
            y = upload(mi.Float, [value], np.float32) + dr.arange(mi.Float, 4)
            dr.eval(y)
            np.testing.assert_array_equal(y.numpy(), value + np.arange(4))

        kernels.append(jit_kernels(run)[0])
    assert kernels[0] == kernels[1]


def test_upload_keeps_dtype_and_shape_flat(mitsonar_mod):
    import mitsuba as mi

    from mitsonar.plugins.jit_arrays import upload

    a = upload(mi.UInt32, np.arange(12).reshape(3, 4), np.uint32)
    np.testing.assert_array_equal(a.numpy(), np.arange(12))
    b = upload(mi.Bool, [True, False, True], np.bool_)
    np.testing.assert_array_equal(b.numpy(), [True, False, True])
