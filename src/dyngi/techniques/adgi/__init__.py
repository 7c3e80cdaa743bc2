"""ADGI (Datta et al. 2022): heuristics, Algorithm 3 moving average; see :mod:`.heuristics` and
:mod:`.moving_average`. The package imports nothing heavy on its own."""
