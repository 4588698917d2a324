"""The motion matrices under the name the registration first gave them: they live in
:mod:`hdrcore.geometry`, with the sampling kernel."""

from __future__ import annotations

from ..geometry import (
    affine_part,
    apply,
    compose,
    corner_error,
    homogeneous,
    identity,
    invert,
    is_affine,
    nearest_in_frame,
    pair_from_reference,
    rigid_matrix,
    rigid_parameters,
    scale_matrix,
    similarity_matrix,
    similarity_parameters,
    to_reference,
)

__all__ = [
    "affine_part",
    "apply",
    "compose",
    "corner_error",
    "homogeneous",
    "identity",
    "invert",
    "is_affine",
    "nearest_in_frame",
    "pair_from_reference",
    "rigid_matrix",
    "rigid_parameters",
    "scale_matrix",
    "similarity_matrix",
    "similarity_parameters",
    "to_reference",
]
