"""The one luminance (dyngi.transport.color): host (NumPy) and device (Dr.Jit) weigh colour alike, and the
weights are Rec. 709's Y (white 1, pure green 0.715)."""
import numpy as np


def test_luminance_host_equals_device(backend):
    from dyngi.backend import mi
    from dyngi.transport.color import luminance

    c = np.array([[1.0, 1.0, 1.0], [0.0, 1.0, 0.0], [0.3, 0.2, 5.0]])
    host = luminance(c)
    dev = np.asarray(luminance(mi.Color3f(c[:, 0], c[:, 1], c[:, 2])))
    assert np.allclose(host, dev, rtol=1e-6)
    assert np.isclose(host[0], 1.0, atol=1e-5) and np.isclose(host[1], 0.71516)
