"""Sampling routines: RNG streams, light sampling strategies (sample/pdf pairs)."""
