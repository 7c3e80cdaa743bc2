"""Probe-volume state: the arrays every DDGI-family technique reads and writes.

A volume is a :class:`~dyngi.probes.grid.ProbeGrid` plus, per probe ``p``:

* ``irradiance[p]`` -- ``T_irr x T_irr x 3`` octahedral texels (1-texel border,
  see :mod:`dyngi.sampling.octahedral`). **Convention**: a texel with direction
  ``n`` stores ``E(n) / pi``, the cosine-weighted mean of the incident radiance
  over the hemisphere around ``n`` (radiance units). A closed furnace of
  radiance ``L`` therefore stores ``L``; :class:`~dyngi.probes.query.ProbeQuery`
  returns the irradiance ``E = pi * stored``.
* ``distance[p]`` -- ``T_d x T_d x 2`` texels: mean and mean squared distance
  to the nearest surface in a sharp cosine-power lobe around the texel
  direction (DDGI Sec. 3.2; the moments of the Chebyshev visibility test).
* ``irradiance_count[p]`` / ``distance_count[p]`` -- ``T x T`` uint32 sample
  counts per texel (samples the temporal accumulator has merged, capped by the
  encoding; ADGI's moving average divides by them, Algorithm 3). They are
  device state like the atlases (``device.irradiance_count`` /
  ``device.distance_count``).
* ``offsets[p]`` -- relocation offset (world units, |component| bounded by a
  fraction of the spacing); ``states[p]`` -- 1 active, 0 inactive.
* ``radiance[p]`` / ``radiance_count[p]`` -- the optional third atlas, allocated
  when a technique asks for a radiance layer (:meth:`ProbeVolume.add_radiance_layer`,
  ``R`` = ``radiance_texels`` per side; ADGI's, :mod:`dyngi.techniques.adgi.radiance`):
  the ``(R-2)^2`` *interior* octahedral texels of an ``R x R`` map (row-major, no
  border: nothing filters it bilinearly, see :meth:`ProbeVolume.radiance_texel_of`)
  of mean radiance (Color3f interleaved, ``P*(R-2)^2*3`` floats) and a uint32
  sample count each. It is device state only (``device.radiance`` /
  ``device.radiance_count``): no host copy, :meth:`ProbeVolume.sync` does not
  touch it, :meth:`ProbeVolume.radiance_host` reads it back.

The host copy (NumPy, what blending and tests use) and the device copy
(flat Dr.Jit arrays, what kernels gather from) are kept in one
:class:`ProbeVolume`; :meth:`ProbeVolume.sync` uploads after host updates.
The volume owns every texel store of a probe technique: the atlases, their
reset (:meth:`ProbeVolume.reset`) and their memory (:meth:`ProbeVolume.memory_parts`).
Relocation and classification (:mod:`dyngi.probes.states`) move probes and switch
their states but touch no atlas: a relocated probe keeps its texels, the radiance
layer's included.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from ..sampling.octahedral import direction_to_texel_coords
from .arrays import upload
from .grid import PROBE_ACTIVE, ProbeGrid
from .trace import DEFAULT_HIT_LOBES, check_hit_lobes, check_two_sided


class _DeviceBacked:
    """A host atlas of :class:`ProbeVolumeState` that is refreshed from the device before any access."""

    def __set_name__(self, owner, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, state, owner=None):
        if state is None:
            return self
        state._refresh()
        return getattr(state, self.slot)

    def __set__(self, state, value: np.ndarray) -> None:
        state._refresh()
        setattr(state, self.slot, value)


class ProbeVolumeState:
    """Temporal state of a probe volume (host arrays; shapes documented in the module docstring).

    ``irradiance`` and ``distance`` may be newer on the device (the hysteresis
    blend updates them there every frame): :meth:`device_is_newer` registers a
    function that copies them back, and the host arrays are refreshed the
    first time they are read after that -- a frame that never looks at the host
    copy pays no Dr.Jit -> NumPy transfer.
    """

    def __init__(self, irradiance: np.ndarray, distance: np.ndarray, offsets: np.ndarray, states: np.ndarray,
                 updates: np.ndarray, extra: dict | None = None, irradiance_count: np.ndarray | None = None,
                 distance_count: np.ndarray | None = None):
        self._irradiance = irradiance   # (P, Ti, Ti, 3) float32, stores E/pi
        self._distance = distance       # (P, Td, Td, 2) float32, (mean, mean of squares)
        self.offsets = offsets          # (P, 3) float32 relocation offsets
        self.states = states            # (P,) uint8, 1 active / 0 inactive
        self.updates = updates          # (P,) int32, number of blends received (0: no history yet)
        self.extra = extra if extra is not None else {}  # technique-specific arrays
        self._irradiance_count = (irradiance_count if irradiance_count is not None
                                  else np.zeros(irradiance.shape[:3], np.uint32))   # (P, Ti, Ti)
        self._distance_count = (distance_count if distance_count is not None
                                else np.zeros(distance.shape[:3], np.uint32))       # (P, Td, Td)
        self._pull = None

    def device_is_newer(self, pull) -> None:
        """``pull(name, out)`` will copy atlas ``name`` ('irradiance' / 'distance') into ``out`` when read."""
        self._pull = pull

    def _refresh(self) -> None:
        if self._pull is not None:
            pull, self._pull = self._pull, None
            for name in ("irradiance", "distance", "irradiance_count", "distance_count"):
                pull(name, getattr(self, "_" + name))

    irradiance = _DeviceBacked()
    distance = _DeviceBacked()
    irradiance_count = _DeviceBacked()
    distance_count = _DeviceBacked()

    @staticmethod
    def zeros(n_probes: int, irradiance_texels: int, distance_texels: int) -> "ProbeVolumeState":
        P, Ti, Td = int(n_probes), int(irradiance_texels), int(distance_texels)
        return ProbeVolumeState(
            irradiance=np.zeros((P, Ti, Ti, 3), np.float32),
            distance=np.zeros((P, Td, Td, 2), np.float32),
            offsets=np.zeros((P, 3), np.float32),
            states=np.full(P, PROBE_ACTIVE, np.uint8),
            updates=np.zeros(P, np.int32),
            extra={"n_probes": P},
        )

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.irradiance)) and np.all(np.isfinite(self.distance))
                    and np.all(np.isfinite(self.offsets)))


@dataclass
class DeviceAtlas:
    """Flat Dr.Jit mirrors of a :class:`ProbeVolumeState` for gathers inside kernels."""

    irradiance: "mi.Float"      # P*Ti*Ti*3
    distance: "mi.Float"        # P*Td*Td*2
    positions: "mi.Float"       # P*3 (lattice + offsets)
    states: "mi.UInt32"         # P
    probe_data: "mi.Float" = None   # P*4: position xyz and 1.0 (active) / 0.0 -- one packet gather per probe
    irradiance_count: "mi.UInt32" = None   # P*Ti*Ti samples merged per texel
    distance_count: "mi.UInt32" = None     # P*Td*Td
    radiance: "mi.Float" = None            # P*(R-2)^2*3 (the radiance layer, when asked for; no host copy)
    radiance_count: "mi.UInt32" = None     # P*(R-2)^2


class ProbeVolume:
    """A probe grid with its texel layout, host state and device mirror.

    Parameters
    ----------
    grid : ProbeGrid
    irradiance_texels : int = 8   texels per side incl. the 1-texel border (DDGI default 8)
    distance_texels : int = 16    texels per side incl. border (DDGI default 16)
    max_distance : float | None   distances are clamped to this (default 1.5 x the largest spacing, at
                                  least the cell diagonal: a probe must see across its cell, issue 11 item 2)
    two_sided : str = 'enclosed'  the two-sided rule: how the tracer signs a ray that hits the back of a
                                  two-sided surface, for the distance moments, relocation and classification
                                  alike (:mod:`dyngi.probes.trace`, "The two-sided rule")
    hit_lobes : str = 'layered'   the hit-lobe rule: which lobes a probe-ray hit reflects as diffuse light
                                  (:mod:`dyngi.probes.trace`, :func:`~dyngi.probes.trace.hit_albedo`; ours)
    radiance_texels : int | None  a radiance layer of this many texels per side incl. the border (only the
                                  interior is stored; :meth:`add_radiance_layer`); None (default): none

    ``geometry``: the Mitsuba scene the probes were last traced in (set by the tracer,
    :func:`~dyngi.probes.trace.trace_probe_rays`); relocation checks its moves against it
    (:class:`~dyngi.probes.states.ProbeStates`).
    """

    def __init__(self, grid: ProbeGrid, irradiance_texels: int = 8, distance_texels: int = 16,
                 max_distance: float | None = None, two_sided: str = "enclosed",
                 hit_lobes: str = DEFAULT_HIT_LOBES, radiance_texels: int | None = None):
        for name, t in (("irradiance_texels", irradiance_texels), ("distance_texels", distance_texels)):
            if int(t) < 3:
                raise DyngiError(f"parameter '{name}' must be >= 3 (1-texel border on each side), got {t}")
        self.grid = grid
        self.irradiance_texels = int(irradiance_texels)
        self.distance_texels = int(distance_texels)
        self.max_distance = (float(max_distance) if max_distance is not None
                             else max(1.5 * grid.max_spacing, grid.cell_diagonal))
        self.two_sided = check_two_sided(two_sided)
        self.hit_lobes = check_hit_lobes(hit_lobes)
        self.geometry = None
        self.state = ProbeVolumeState.zeros(grid.n_probes, self.irradiance_texels, self.distance_texels)
        self.device: DeviceAtlas | None = None
        self.radiance_texels: int | None = None     # R of the radiance layer (None: no radiance layer)
        self.sync()
        if radiance_texels is not None:
            self.add_radiance_layer(radiance_texels)

    # -- the radiance layer (the third atlas) -------------------------------------------------------
    def add_radiance_layer(self, texels: int) -> None:
        """Allocate the radiance layer: per probe the ``(texels-2)^2`` interior texels of a ``texels x texels``
        octahedral map, mean radiance (zero) and a sample count (zero), on the device (module docstring).
        Asking again for the same size keeps the layer; another size raises (one radiance layer per volume)."""
        R = int(texels)
        if R < 3:
            raise DyngiError(f"parameter 'radiance_texels' must be >= 3 (1-texel border on each side), got {texels}")
        if self.radiance_texels is not None:
            if R != self.radiance_texels:
                raise DyngiError(f"the probe volume already has a radiance layer of {self.radiance_texels} texels "
                                 f"per side, asked for {R}")
            return
        self.radiance_texels = R
        n = self.n_probes * self.radiance_interior
        d = self.device
        d.radiance = dr.zeros(mi.Float, n * 3)
        d.radiance_count = dr.zeros(mi.UInt32, n)
        dr.eval(d.radiance, d.radiance_count)

    @property
    def radiance_interior(self) -> int:
        """Interior radiance texels per probe, ``(R-2)^2`` (0 without a radiance layer)."""
        return 0 if self.radiance_texels is None else (self.radiance_texels - 2) ** 2

    def radiance_texel_of(self, w):
        """The interior radiance texel (row-major, ``0 .. (R-2)^2 - 1``) that direction ``w`` (Vector3f) falls
        in; directions on the border clamp to the nearest interior texel."""
        R = self.radiance_texels
        c = direction_to_texel_coords(w, R)
        ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, R - 3)
        iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, R - 3)
        return mi.UInt32(iy * (R - 2) + ix)

    def radiance_host(self) -> tuple[np.ndarray, np.ndarray]:
        """The radiance layer read back: ``(value (P, (R-2)^2, 3) float32, count (P, (R-2)^2) uint32)``."""
        d, n = self.device, self.radiance_interior
        return (np.asarray(d.radiance, np.float32).reshape(self.n_probes, n, 3),
                np.asarray(d.radiance_count, np.uint32).reshape(self.n_probes, n))

    @property
    def n_probes(self) -> int:
        return self.grid.n_probes

    def positions(self) -> np.ndarray:
        """(P, 3) float64 current probe positions (lattice + relocation offsets)."""
        return self.grid.positions(self.state.offsets.astype(np.float64))

    def active_indices(self) -> np.ndarray:
        return np.flatnonzero(self.state.states == PROBE_ACTIVE).astype(np.uint32)

    def reset(self) -> None:
        """Forget all history (irradiance, distance, update counts, the radiance layer); keeps offsets and
        states."""
        self.state.irradiance[:] = 0
        self.state.distance[:] = 0
        self.state.updates[:] = 0
        self.state.irradiance_count[:] = 0
        self.state.distance_count[:] = 0
        self.state.extra.clear()
        self.state.extra["n_probes"] = self.n_probes
        self.sync()
        R, self.radiance_texels = self.radiance_texels, None
        if R is not None:
            self.add_radiance_layer(R)

    def sync(self, what: tuple = ("irradiance", "distance", "positions", "states")) -> None:
        """Upload host arrays to the device mirror (only the named parts once it exists).

        'irradiance' and 'distance' upload their texel counts too.
        """
        s = self.state
        if self.device is None:
            what = ("irradiance", "distance", "positions", "states")
            self.device = DeviceAtlas(None, None, None, None, None)
        d = self.device
        if "irradiance" in what:
            d.irradiance = upload(s.irradiance.astype(np.float32))
            d.irradiance_count = upload(s.irradiance_count.astype(np.uint32), mi.UInt32)
        if "distance" in what:
            d.distance = upload(s.distance.astype(np.float32))
            d.distance_count = upload(s.distance_count.astype(np.uint32), mi.UInt32)
        if "positions" in what:
            d.positions = upload(self.positions().astype(np.float32))
        if "states" in what:
            d.states = upload(s.states.astype(np.uint32), mi.UInt32)
        if "positions" in what or "states" in what:
            pd = np.concatenate([self.positions(), (s.states != 0)[:, None]], axis=1)
            d.probe_data = upload(pd.astype(np.float32))
        dr.eval(d.irradiance, d.distance, d.positions, d.states, d.probe_data, d.irradiance_count,
                d.distance_count)

    def memory_parts(self) -> dict:
        """The arrays the volume allocates, by part: ``irradiance`` / ``visibility`` (the atlases and their texel
        counts, host and device), ``probe_state`` (offsets, states, update counts, device positions, states and
        probe packets), ``radiance_layer`` (the radiance atlas and its counts, device only; empty without one).
        A newer device atlas is pulled into the host copy first. For measured memory (NumPy ``nbytes`` and
        Dr.Jit arrays alike; ADGI's :meth:`memory_per_probe <dyngi.techniques.adgi.technique.ADGITechnique
        .memory_per_probe>`)."""
        st, dev = self.state, self.device
        st._refresh()
        return {
            "irradiance": [st._irradiance, st._irradiance_count, dev.irradiance, dev.irradiance_count],
            "visibility": [st._distance, st._distance_count, dev.distance, dev.distance_count],
            "probe_state": [st.offsets, st.states, st.updates, dev.positions, dev.states, dev.probe_data],
            "radiance_layer": ([dev.radiance, dev.radiance_count] if self.radiance_texels is not None else []),
        }

    def copy_state(self) -> ProbeVolumeState:
        s = self.state
        return ProbeVolumeState(s.irradiance.copy(), s.distance.copy(), s.offsets.copy(), s.states.copy(),
                                s.updates.copy(), {k: np.copy(v) for k, v in s.extra.items()},
                                s.irradiance_count.copy(), s.distance_count.copy())
