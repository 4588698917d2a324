"""Panels of the inspector: each one draws result objects of ``hdrcore``; none computes them."""
