"""Persistent Metropolis chains over probe position x direction (ADGI, Datta et al. 2022, Sec. 3.3, 4.8-4.9,
Algorithms 1 and 5).

Each chain is one lane of Dr.Jit arrays; its state (:class:`ChainState`)
survives across frames, so a few iterations per frame accrue a long chain
over time (Sec. 3.3, "Mixing-time"). Per frame, :meth:`MetropolisChains.run`
does ``M`` random-walk steps (Algorithm 5) per chain against a target ``h``
(an unnormalised density, a Dr.Jit function of the state); the first ``K``
are burn-in and every step after them yields one sample (Algorithm 1).

State space
-----------
* position: a point of the box ``[lo, hi]`` (any units; ADGI uses continuous
  probe-grid coordinates, so a probe is the lattice point nearest to it). An
  axis with ``lo == hi`` is frozen (a 1D or 2D position space).
* direction (optional): a unit vector; the target density is per solid angle.

Proposals (Algorithm 5, symmetric, so the acceptance ratio is ``h(x')/h(x)``)
------------------------------------------------------------------------------
* position: ``x + N(0, sigma_p)`` per axis, reflected back into the box. A
  reflected Gaussian is symmetric (the reflections are isometries), so the
  chain's stationary density is ``h`` restricted to the box. Reflection at the
  box faces is ours; the paper is silent on boundaries.
* direction: ``normalize(w + sigma_w (g1 s + g2 t))`` with ``(s, t)`` a tangent
  frame of ``w`` and ``g1, g2`` standard normals: its density depends only on
  the angle between ``w`` and ``w'``, hence symmetric w.r.t. solid angle (ours;
  the paper says only "zero-mean Gaussian noise" and a step of about
  ``sqrt(pi/256)``, Sec. 4.8).

Acceptance: ``accept = u * h(x) < h(x')`` with ``u ~ U(0, 1)``; a chain whose
current ``h`` is 0 accepts any move (it wanders until it finds the support).
``h`` of the current state is re-evaluated at the start of every frame, since
the target changes between frames (Algorithm 1 line 4 passes ``h(x_i)``).

Samples: Algorithm 1 uses the states after iterations ``i > K`` (0-based, so
``M - K - 1`` of them); we use every state after iteration ``i >= K``, i.e.
``M - K`` samples per chain per frame (ours; the two differ by one).
Random numbers come from a per-chain ``mi.PCG32`` stream whose state is
seeded from (seed, frame, stream) as an opaque value: a new frame compiles
nothing. The ``M`` iterations are one symbolic ``dr.while_loop`` (traced
once; measured 10 ms of Python tracing per call when unrolled).

Parameters
----------
lo, hi : 3 floats            box of the position component
position_step : 3 floats     std-dev of the position step per axis (ADGI: proportional to the spacing)
direction_step : float|None  std-dev (radians) of the tangent step; ``None``: no direction component
burn_in : int = K            iterations per frame whose states are not used
iterations : int = M         iterations per frame (``M > K``)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from .rng import make_sampler, mix_seed

#: ADGI's angular step, ``sqrt(pi / 256)`` radians (Sec. 4.8).
ADGI_DIRECTION_STEP = float(np.sqrt(np.pi / 256.0))


@dataclass
class ChainState:
    """Persistent state of ``n`` chains (one lane each).

    position : Vector3f        current position (inside the box)
    direction : Vector3f|None  current unit direction
    """

    position: "mi.Vector3f"
    direction: "mi.Vector3f | None" = None

    @property
    def n(self) -> int:
        return dr.width(self.position)


@dataclass
class ChainSamples:
    """The states a frame's iterations after burn-in yielded: lane ``j * n + c`` is chain ``c`` after
    iteration ``K + j``.

    position, direction : as :class:`ChainState` (``direction`` None without a direction component)
    value : Float       the target ``h`` at the sample
    chain : UInt32      chain index of each sample
    accepted : Bool     whether the step that produced the sample was accepted
    """

    position: "mi.Vector3f"
    direction: "mi.Vector3f | None"
    value: "mi.Float"
    chain: "mi.UInt32"
    accepted: "mi.Bool"

    @property
    def n(self) -> int:
        return dr.width(self.value)


def reflect_into(x, lo, hi):
    """Fold ``x`` into ``[lo, hi]`` by mirror reflection at the ends (any distance); ``lo == hi`` gives ``lo``."""
    length = hi - lo
    two = 2.0 * length
    y = x - lo
    y = y - two * dr.floor(y / dr.select(two > 0.0, two, 1.0))
    y = dr.select(y > length, two - y, y)
    return lo + dr.select(length > 0.0, y, 0.0)


def propose_direction(w, step, u2):
    """Symmetric random-walk step of a unit direction (see the module docstring)."""
    g = mi.warp.square_to_std_normal(u2)
    frame = mi.Frame3f(w)
    return dr.normalize(w + step * (g.x * frame.s + g.y * frame.t))


class MetropolisChains:
    """Random-walk Metropolis over position x direction; see the module docstring."""

    def __init__(self, lo, hi, position_step, direction_step: float | None = ADGI_DIRECTION_STEP,
                 burn_in: int = 4, iterations: int = 8, stream: int = 0):
        self.lo = np.asarray(lo, np.float64).reshape(3)
        self.hi = np.asarray(hi, np.float64).reshape(3)
        self.position_step = np.broadcast_to(np.asarray(position_step, np.float64), (3,)).copy()
        if np.any(self.hi < self.lo) or not np.all(np.isfinite(np.r_[self.lo, self.hi])):
            raise DyngiError(f"chain box must have lo <= hi, got lo={self.lo.tolist()} hi={self.hi.tolist()}")
        if np.any(self.position_step < 0) or not np.all(np.isfinite(self.position_step)):
            raise DyngiError(f"chain position_step must be >= 0, got {self.position_step.tolist()}")
        if direction_step is not None and not (np.isfinite(direction_step) and direction_step > 0):
            raise DyngiError(f"chain direction_step must be > 0 (or None), got {direction_step}")
        self.burn_in, self.iterations = int(burn_in), int(iterations)
        if self.burn_in < 0 or self.iterations <= self.burn_in:
            raise DyngiError(f"chains need 0 <= burn_in < iterations, got burn_in={burn_in}, "
                             f"iterations={iterations}")
        self.direction_step = None if direction_step is None else float(direction_step)
        self.stream = int(stream)

    @property
    def samples_per_chain(self) -> int:
        return self.iterations - self.burn_in

    # -- Dr.Jit constants (opaque: a change of box or step size recompiles nothing) --
    def _opaque(self):
        lo = dr.opaque(mi.Vector3f, [float(v) for v in self.lo])
        hi = dr.opaque(mi.Vector3f, [float(v) for v in self.hi])
        sp = dr.opaque(mi.Vector3f, [float(v) for v in self.position_step])
        sw = dr.opaque(mi.Float, self.direction_step or 0.0)
        return lo, hi, sp, sw

    def initial_state(self, n: int, seed: int) -> ChainState:
        """``n`` chains at uniform random positions in the box and uniform random directions."""
        sampler = make_sampler(int(n), seed, 0, self.stream + 0x51)
        lo, hi, _, _ = self._opaque()
        u = mi.Vector3f(sampler.next_1d(), sampler.next_1d(), sampler.next_1d())
        pos = dr.fma(u, hi - lo, lo)
        d = mi.warp.square_to_uniform_sphere(sampler.next_2d()) if self.direction_step is not None else None
        state = ChainState(pos, d)
        dr.eval(state.position, state.direction)
        return state

    def run(self, state: ChainState, target: Callable, seed: int, frame: int):
        """``M`` random-walk iterations of every chain against ``target``.

        ``target(position, direction)`` (``direction`` None without a direction
        component) returns the unnormalised density ``h`` (``mi.Float``, >= 0).
        Returns ``(new_state, ChainSamples)``; ``state`` is not modified.
        """
        n = state.n
        has_dir = self.direction_step is not None
        if has_dir != (state.direction is not None):
            raise DyngiError("chain state and sampler disagree on the direction component")
        # per-lane state and stream hashed from (lane, seed) as Mitsuba's independent sampler does:
        # PCG32 streams with consecutive sequence numbers are correlated
        a, b = mi.sample_tea_32(dr.opaque(mi.UInt32, mix_seed(seed, frame, self.stream)),
                                dr.arange(mi.UInt32, n), 4)
        rng = mi.PCG32(n, mi.UInt64(a) | (mi.UInt64(b) << 32), mi.UInt64(b))
        lo, hi, sp, sw = self._opaque()
        x = mi.Vector3f(state.position)
        w = mi.Vector3f(state.direction) if has_dir else mi.Vector3f(0.0, 0.0, 1.0)
        y = mi.Float(target(x, w if has_dir else None))
        n_out = n * self.samples_per_chain
        out_p = dr.zeros(mi.Vector3f, n_out)
        out_w = dr.zeros(mi.Vector3f, n_out) if has_dir else None
        out_v = dr.zeros(mi.Float, n_out)
        out_a = dr.zeros(mi.Bool, n_out)
        lane = dr.arange(mi.UInt32, n)
        K, M = self.burn_in, self.iterations
        nn = dr.opaque(mi.UInt32, n)

        def u2(r):
            return mi.Point2f(r.next_float32(), r.next_float32())

        def cond(i, x, w, y, rng):
            return i < M

        def body(i, x, w, y, rng):
            # -- propose (Algorithm 5 line 2) --
            g = mi.warp.square_to_std_normal(u2(rng))
            gz = mi.warp.square_to_std_normal(u2(rng)).x
            xp = reflect_into(x + sp * mi.Vector3f(g.x, g.y, gz), lo, hi)
            wp = propose_direction(w, sw, u2(rng)) if has_dir else w
            # -- accept / reject (lines 3-8) --
            yp = dr.maximum(mi.Float(target(xp, wp if has_dir else None)), 0.0)
            yp = dr.select(dr.isfinite(yp), yp, 0.0)
            acc = (rng.next_float32() * y < yp) | (y <= 0.0)
            x = dr.select(acc, xp, x)
            w = dr.select(acc, wp, w)
            y = dr.select(acc, yp, y)
            # -- every iteration after burn-in yields a sample (Algorithm 1 lines 5-6) --
            keep = i >= K
            idx = lane + (i - K) * nn
            dr.scatter(out_p, x, idx, keep)
            if has_dir:
                dr.scatter(out_w, w, idx, keep)
            dr.scatter(out_v, y, idx, keep)
            dr.scatter(out_a, acc, idx, keep)
            return i + 1, x, w, y, rng

        # one symbolic loop (Dr.Jit traces the body once, whatever M is)
        _, x, w, y, rng = dr.while_loop((mi.UInt32(0), x, w, y, rng), cond, body)
        if not has_dir:
            w = None
        new = ChainState(x, w)
        chain = dr.arange(mi.UInt32, n_out) % dr.opaque(mi.UInt32, n)
        samples = ChainSamples(out_p, out_w, out_v, chain, out_a)
        dr.eval(new.position, new.direction, samples.position, samples.direction, samples.value,
                samples.chain, samples.accepted)
        return new, samples
