"""Progressive accumulation (dyngi.transport.accumulate): the sample-weighted running mean of frames,
restarted by a frame that moved or changed size."""
import numpy as np


def test_progressive_mean_is_the_sample_weighted_mean(backend):
    from dyngi.backend import mi
    from dyngi.transport.accumulate import ProgressiveMean

    rng = np.random.default_rng(0)
    frames = [rng.random(64).astype(np.float32) for _ in range(5)]
    spp = [1, 3, 2, 4, 1]
    acc = ProgressiveMean()
    for f, s in zip(frames, spp):
        acc.add(mi.Float(f), mi.Float(0.5 * f), samples=s)
    want = np.average(np.stack(frames), axis=0, weights=spp)
    assert np.allclose(np.asarray(acc.mean), want, rtol=1e-5, atol=1e-6)
    assert np.allclose(np.asarray(acc.mean_ind), 0.5 * want, rtol=1e-5, atol=1e-6)
    assert acc.frames == 5 and acc.samples == sum(spp)
    # a frame that moved restarts the mean; so does a new resolution
    acc.add(mi.Float(frames[0]), samples=2, accumulate=False)
    assert np.array_equal(np.asarray(acc.mean), frames[0]) and acc.frames == 1 and acc.samples == 2
    acc.add(mi.Float(np.ones(16, np.float32)))
    assert np.array_equal(np.asarray(acc.mean), np.ones(16)) and acc.frames == 1
