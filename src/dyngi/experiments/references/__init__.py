"""Ground-truth references of a frame, cached on disk.

:mod:`~dyngi.experiments.references.cache`   keys, directory, atomic entries, the lock that renders a
                                             missing entry once (no Dr.Jit: executors import it)
:mod:`~dyngi.experiments.references.path`    Mitsuba's ``path`` integrator: full and indirect-by-difference
                                             references, their two-halves noise estimate, chunks
:mod:`~dyngi.experiments.references.indirect` dyngi's path tracer in its indirect-only mode
:mod:`~dyngi.experiments.references.clamped` clamped path tracing (SMC-IR Sec. 5.4): what infinitely many
                                             VPLs give
:mod:`~dyngi.experiments.references.tracked` the 8 tracked pixels (SMC-IR Sec. 5.2) with many more samples

Many frames on an executor (a cluster): :mod:`dyngi.experiments.reference_job`, which imports these
modules (never the reverse).
"""
