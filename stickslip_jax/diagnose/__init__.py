"""Diagnosis: locate where model and recordings differ, name and add the missing physics."""

from .catalogue import CATALOGUE, NAMES, Candidate, Probe, candidate
from .concealed import CANNOT_SHOW, EFFECTS, with_effect
from .locate import RecordingResidual, analyse_recording, mismatch_entries, residual_peaks
from .run import CandidateResult, Diagnosis, diagnose

__all__ = [
    "CANNOT_SHOW", "CATALOGUE", "EFFECTS", "NAMES", "Candidate", "CandidateResult",
    "Diagnosis", "Probe", "RecordingResidual", "analyse_recording", "candidate", "diagnose",
    "mismatch_entries", "residual_peaks", "with_effect",
]
