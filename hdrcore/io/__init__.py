"""Reading brackets and writing results; every file format lives behind this package.

Numerical code elsewhere in ``hdrcore`` takes arrays, never paths.
"""

from .apex import bracket_sequence, snap_exposure_time, snap_f_number
from .atomic import atomic_write, check_output_path
from .bracket import (
    Bracket,
    BracketWarning,
    brightness_order,
    expand_paths,
    load_bracket,
    load_frame,
    recorded_exposures,
)
from .exif import ExifData, read_exif
from .exr import EXR_COMPRESSIONS, read_exr, write_exr
from .frame import Frame, FrameMetadata, RawCFA, apply_orientation
from .header import MAX_FRAME_PIXELS, frame_pixels
from .ldr import read_ldr
from .preview import encode_png, write_png
from .raw import (
    RAW_EXTENSIONS,
    OpticalBlack,
    is_raw_path,
    matrix_neutral,
    optical_black_noise,
    read_raw,
)
from .times import parse_seconds, read_exposure_times

__all__ = [
    "EXR_COMPRESSIONS",
    "MAX_FRAME_PIXELS",
    "RAW_EXTENSIONS",
    "Bracket",
    "BracketWarning",
    "ExifData",
    "Frame",
    "FrameMetadata",
    "OpticalBlack",
    "RawCFA",
    "apply_orientation",
    "atomic_write",
    "bracket_sequence",
    "brightness_order",
    "check_output_path",
    "encode_png",
    "expand_paths",
    "frame_pixels",
    "is_raw_path",
    "load_bracket",
    "load_frame",
    "matrix_neutral",
    "optical_black_noise",
    "parse_seconds",
    "read_exif",
    "read_exposure_times",
    "read_exr",
    "read_ldr",
    "read_raw",
    "recorded_exposures",
    "snap_exposure_time",
    "snap_f_number",
    "write_exr",
    "write_png",
]
