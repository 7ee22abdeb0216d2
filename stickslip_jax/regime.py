"""Stepping or scanning: one definition for every command.

A sawtooth drive **steps** when the slider slips on each flyback, so that it gains a
net step per period; it **scans** when the slider follows the piezo back and forth
(Lu 2015 §II), the contact sticking or only pre-sliding. Without a friction state in
a recording the two are told apart by the phase-locked net step per period against
the peak-to-peak output within a period (the swing): the drive steps when the step
exceeds :data:`STEPPING_FRACTION` of the swing.

Why a twentieth: on the paper's profile the motions that are not slip stay under
1 % of the swing per period at every drive of 10-80 V and 50-1000 Hz (pre-sliding
drift at 50-500 Hz, about 0.1 %; the piezo element's own dynamics at 1 kHz, 0.9 %
whatever the amplitude), while slip grows from the 0-amplitude threshold to 20-45 %
at 40-80 V. A twentieth sits five times above the first and lets a drive count as
stepping from a few tens of nanometres per micrometre of swing (30 V at 50 Hz:
133 nm per period, 9 % of its swing). Drives just above the threshold are the
0-amplitude effect's domain, where velocity is not a monotone function of amplitude:
commands that invert velocity say so.
"""

from __future__ import annotations

STEPPING_FRACTION = 0.05
"""A drive steps when its net step per period exceeds this fraction of its swing [-]."""


def drive_steps(step_m: float, swing_m: float) -> bool:
    """Whether a sawtooth drive with net step ``step_m`` [m] per period and output
    swing ``swing_m`` [m] peak-to-peak within a period steps (see module docstring).
    A NaN step (fewer than two whole periods) does not."""
    return bool(abs(step_m) > STEPPING_FRACTION * swing_m)
