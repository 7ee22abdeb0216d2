"""Batched sweeps over sawtooth drives: velocity maps and what is built on them."""

from .engine import SweepRun, auto_chunk, run_grid, samples_needed, sawtooth_samples
from .grid import DriveGrid, parse_values
from .inverse import DriveChoice, drive_for_velocity, parse_velocity
from .map import VelocityMap, velocity_map
from .threshold import ratio_study, step_vs_amplitude, zero_amplitude_threshold
from .velocity import PointVelocity, period_end_positions, steady_velocity
from .zba_surface import (
    SurfaceFit,
    ZbaPoints,
    ZbaSurface,
    ZbaSurfaceElastoPlastic,
    fit_zba_points,
    fit_zba_surface,
    load_zba_surface,
    with_zba_surface,
)

__all__ = [
    "DriveChoice", "DriveGrid", "PointVelocity", "SweepRun", "VelocityMap", "auto_chunk",
    "drive_for_velocity", "parse_values", "parse_velocity", "period_end_positions",
    "run_grid", "samples_needed", "sawtooth_samples", "steady_velocity", "velocity_map",
    "SurfaceFit", "ZbaPoints", "ZbaSurface", "ZbaSurfaceElastoPlastic", "fit_zba_points",
    "fit_zba_surface", "load_zba_surface", "with_zba_surface", "step_vs_amplitude",
    "zero_amplitude_threshold", "ratio_study",
]
