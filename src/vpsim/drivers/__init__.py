"""Drivers: what turns a drive cycle into the speed demand a simulation method follows."""

from .smoothing import (
    SmoothingDriver,
    bump_kernel,
    bump_kernel_cdf,
    bump_kernel_moment,
    bump_normalisation,
    smooth_reference,
)

__all__ = [
    "SmoothingDriver",
    "bump_kernel",
    "bump_kernel_cdf",
    "bump_kernel_moment",
    "bump_normalisation",
    "smooth_reference",
]
