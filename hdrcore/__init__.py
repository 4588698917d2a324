"""hdrcore: exposure brackets to HDR after Cerman & Hlavac (2006)."""

__version__ = "0.1.0"
