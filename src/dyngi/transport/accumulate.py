"""Progressive accumulation: a running mean of frames while nothing moves (one for every technique).

The mean is weighted by samples, ``mean += (L - mean) * n / (N + n)`` for a frame of ``n`` samples
after ``N``, with the weight an opaque scalar (one kernel for any count; DESIGN's performance rules).
A frame that moved (or changed resolution) restarts the mean. An optional second image (the indirect
part) follows the same weights."""
from __future__ import annotations

from ..backend import dr, mi


class ProgressiveMean:
    """Running mean of per-frame images (``mean``, ``mean_ind``), ``frames`` and ``samples`` so far."""

    def __init__(self):
        self.mean = None
        self.mean_ind = None
        self.frames = 0
        self.samples = 0

    def add(self, L, L_ind=None, samples: int = 1, accumulate: bool = True) -> None:
        """Add a frame of ``samples`` samples per pixel; ``accumulate=False`` (a frame that moved, or
        progressive accumulation off) restarts the mean from it. Evaluates the mean(s)."""
        if accumulate and self.mean is not None and dr.width(self.mean) == dr.width(L):
            a = dr.opaque(mi.Float, samples / (self.samples + samples))
            self.mean = dr.fma(L - self.mean, a, self.mean)
            if L_ind is not None:
                self.mean_ind = dr.fma(L_ind - self.mean_ind, a, self.mean_ind)
            self.frames += 1
            self.samples += samples
        else:
            self.mean, self.mean_ind, self.frames, self.samples = L, L_ind, 1, samples
        if L_ind is not None:
            dr.eval(self.mean, self.mean_ind)
        else:
            dr.eval(self.mean)
