"""Diagnosis: locate where model and recordings differ, name and add the missing physics."""

from .catalogue import CATALOGUE, NAMES, Candidate, Probe, candidate
from .config import DiagnoseConfig
from .locate import RecordingResidual, analyse_recording, mismatch_entries, residual_peaks
from .policy import Policy
from .results import CandidateResult, CandidateStatus, Diagnosis, Verdict
from .run import diagnose

__all__ = [
    "CATALOGUE", "NAMES", "Candidate", "CandidateResult", "CandidateStatus", "DiagnoseConfig",
    "Diagnosis",
    "Policy", "Probe", "RecordingResidual", "Verdict", "analyse_recording", "candidate",
    "diagnose", "mismatch_entries", "residual_peaks",
]
