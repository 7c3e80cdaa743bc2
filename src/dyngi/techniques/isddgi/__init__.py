"""IS-DDGI (Liu et al., I3D 2023): the technique (:mod:`.technique`) and its own parts of the probe
pipeline -- the importance-based ray planner (:mod:`.planner`), the per-set estimator and Algorithm 2's
probe states (:mod:`.estimator`) and the keyed hit shading (:mod:`.shading`). The shared parts live in
:mod:`dyngi.probes`. The package imports nothing heavy on its own."""
