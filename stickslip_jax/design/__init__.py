"""The next recording: drives designed through the differentiable model to settle what
a diagnosis left open (issue #68)."""

from .drives import DriveLimits, candidate_drives, unit_duration
from .evidence import Separation, tolerance_rss
from .hypotheses import Hypothesis, Question, part_specs
from .plan import ExperimentPlan, PlannedRecording, QuestionOutcome, design_experiment

__all__ = [
    "DriveLimits", "ExperimentPlan", "Hypothesis", "PlannedRecording", "Question",
    "QuestionOutcome", "Separation", "candidate_drives", "design_experiment",
    "part_specs", "tolerance_rss", "unit_duration",
]
