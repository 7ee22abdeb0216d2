"""Identification of an actuator from interferometer recordings (Lu 2015 §IV-B)."""

from .dataset import Dataset, period_ends, step_lengths
from .hysteresis_only import HysteresisFit, HysteresisOnlyModel, fit_hysteresis_only
from .parameters import FITTABLE, SCALE_INVARIANT, ParameterMap
from .residuals import TraceResiduals, nrmse_per_recording, simulate_dataset
from .solve import LMSettings, SolveResult, SolveStatus, solve_least_squares
from .steps import STEPS, Identification, StepReport, identify
from .uncertainty import Uncertainty, parameter_uncertainty

__all__ = [
    "FITTABLE", "SCALE_INVARIANT", "STEPS", "Dataset", "HysteresisFit", "HysteresisOnlyModel",
    "Identification", "LMSettings", "ParameterMap", "fit_hysteresis_only",
    "SolveResult", "SolveStatus", "StepReport", "TraceResiduals", "Uncertainty", "identify",
    "nrmse_per_recording", "parameter_uncertainty", "period_ends", "simulate_dataset",
    "solve_least_squares", "step_lengths",
]
