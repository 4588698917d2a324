"""hdrview: a browser inspector for exposure brackets, drawing the results of ``hdrcore``.

Start it with ``hdrview [FILE...|DIR] [--host 127.0.0.1] [--port N] [--root DIR]``.
"""

__all__ = ["__version__"]

__version__ = "0.1.0"
