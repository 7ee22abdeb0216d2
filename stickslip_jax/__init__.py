"""stickslip_jax: differentiable simulation and identification of piezo stick-slip actuators.

The library never changes global JAX settings on import. Enable double precision
before use, and on a CPU let XLA compile the simulator's small loops natively (about
3x faster; :mod:`stickslip_jax.xla_flags`), before JAX's first computation (the CLI
does both for you)::

    import jax
    jax.config.update("jax_enable_x64", True)
    import stickslip_jax as ss
    ss.fast_cpu_loops()
    ss.device_side_gpu_loops()  # on a GPU: loops and branches without the host
    ss.use_compilation_cache()  # optional: a later process reuses the compiled programs
"""

from .adjoint import (
    AbstractAdjoint,
    CheckpointedScan,
    ForwardSensitivities,
    with_forward_jacobian,
)
from .compilation_cache import use_compilation_cache
from .design import DriveLimits, ExperimentPlan, design_experiment
from .diagnose import CATALOGUE, DiagnoseConfig, Diagnosis, Policy, Verdict, diagnose
from .drive_inference import DriveInfo, infer_drive
from .files import InputOverwriteError, OutputExistsError
from .identify import HysteresisOnlyModel, Identification, fit_hysteresis_only, identify
from .io import (
    Recording,
    RecordingError,
    load_recording,
    load_recordings,
    save_recording,
)
from .linear import (
    SpectrumConsistency,
    StickChain,
    StickModes,
    frequency_response,
    spectrum_consistency,
    stick_chain,
    stick_modes,
)
from .model.actuator import Actuator
from .model.base import (
    AbstractExtension,
    AbstractFriction,
    AbstractHysteresis,
    AbstractInputStage,
    AbstractOutputMap,
    CoreState,
    DriveContext,
    ExtensionTerms,
)
from .model.ceim import CEIMElastoPlastic
from .model.contacts import ExtraContacts, multi_contact
from .model.extensions import (
    ChainedOutput,
    ClippedSlewInput,
    Creep,
    CreepSpectrum,
    ExponentialDrift,
    LearnedForce,
    LowPassInput,
    ParallelInputs,
    PeriodicSensorError,
    PositionRipple,
    RateDependentStroke,
    RateLagForm,
    SaturatingViscosity,
    SecondOrderInput,
    SensorOutput,
    ShapedSlewInput,
    SlewLimitedInput,
    StructuralMode,
)
from .model.friction import (
    DEFAULT_ZBA_RATIO,
    ConstantZssElastoPlastic,
    ElastoPlastic,
    LuGre,
    StribeckElastoPlastic,
    transition_alpha,
)
from .model.hemisphere import TiltingHemisphere, with_hemisphere
from .model.hysteresis import PrandtlIshlinskii, default_thresholds
from .model.piezo import PiezoElement
from .model.profiles import LU2015_TABLE, PROFILES, lu2015_slc1720
from .model.registry import (
    FRICTION_LAWS,
    LawParameter,
    friction_law_name,
    register_friction_law,
)
from .model.slider import Slider
from .model.stages import IdentityInput, IdentityOutput
from .noise import noise_sigma
from .params import (
    ParameterError,
    actuator_from_params,
    load_params,
    params_from_actuator,
    save_params,
)
from .signals import make_recording, sawtooth, sine, step
from .simulate import (
    NonFiniteSimulation,
    Trajectory,
    drive_context,
    estimate_error,
    plan_steps,
    simulate,
    simulate_batch,
    simulate_recording,
    simulate_recordings,
    simulate_states,
    stack_drives,
)
from .solvers import EULER, HEUN, RK4, SOLVERS, ExplicitRK
from .stepping import (
    DEFAULT_STEPPING,
    REFERENCE_STEPPING,
    Stepping,
    SteppingError,
    StepPlan,
    fastest_rate,
    mechanical_rate,
)
from .sweep import (
    DriveChoice,
    DriveGrid,
    VelocityMap,
    ZbaPoints,
    ZbaSurface,
    drive_for_velocity,
    fit_zba_points,
    fit_zba_surface,
    load_zba_surface,
    step_vs_amplitude,
    velocity_map,
    with_zba_surface,
    zero_amplitude_threshold,
)
from .sweep.contact_studies import (
    ForceCurve,
    StepCurves,
    force_vs_amplitude,
    preload_study,
    spread_study,
)
from .synthetic import DriveSpec, paper_protocol, simulate_set
from .xla_flags import SMALL_LOOP_BYTES, device_side_gpu_loops, fast_cpu_loops

__version__ = "0.1.0"

__all__ = [
    "AbstractExtension", "AbstractFriction", "AbstractHysteresis", "AbstractInputStage",
    "AbstractOutputMap", "Actuator", "ConstantZssElastoPlastic", "CoreState",
    "DEFAULT_STEPPING", "REFERENCE_STEPPING", "DriveContext", "NonFiniteSimulation",
    "StepPlan", "Stepping",
    "SteppingError", "estimate_error", "fastest_rate", "mechanical_rate", "plan_steps",
    "DriveInfo", "EULER", "ElastoPlastic", "ExplicitRK", "ExtensionTerms", "HEUN",
    "IdentityInput", "IdentityOutput", "InputOverwriteError", "LU2015_TABLE", "LuGre",
    "OutputExistsError", "PROFILES", "ParameterError", "PiezoElement", "PrandtlIshlinskii",
    "RK4", "Recording", "RecordingError", "SOLVERS", "Slider", "SpectrumConsistency",
    "StickChain", "StickModes", "StribeckElastoPlastic", "frequency_response",
    "spectrum_consistency", "stick_chain", "stick_modes",
    "actuator_from_params", "default_thresholds", "drive_context", "infer_drive",
    "load_params", "load_recording", "load_recordings", "lu2015_slc1720", "make_recording",
    "params_from_actuator", "save_params", "save_recording", "sawtooth", "simulate",
    "simulate_batch", "simulate_recording", "simulate_recordings", "simulate_states", "sine",
    "stack_drives", "Trajectory",
    "AbstractAdjoint", "CheckpointedScan", "ForwardSensitivities", "with_forward_jacobian",
    "step", "transition_alpha",
    "HysteresisOnlyModel", "Identification", "fit_hysteresis_only", "identify", "noise_sigma",
    "CATALOGUE", "DiagnoseConfig", "Diagnosis", "Policy", "Verdict", "diagnose",
    "DriveLimits", "ExperimentPlan", "design_experiment",
    "ChainedOutput", "Creep", "CreepSpectrum", "ExponentialDrift", "LearnedForce", "LowPassInput",
    "PeriodicSensorError", "PositionRipple", "RateDependentStroke", "RateLagForm",
    "SaturatingViscosity", "SecondOrderInput",
    "SensorOutput",
    "SlewLimitedInput", "ClippedSlewInput", "ShapedSlewInput", "ParallelInputs", "StructuralMode",
    "DriveChoice", "DriveGrid", "VelocityMap", "ZbaPoints", "ZbaSurface", "drive_for_velocity",
    "fit_zba_points", "fit_zba_surface", "load_zba_surface", "step_vs_amplitude",
    "velocity_map", "with_zba_surface", "zero_amplitude_threshold",
    "DriveSpec", "paper_protocol", "simulate_set",
    "CEIMElastoPlastic", "ExtraContacts", "multi_contact", "ForceCurve", "StepCurves",
    "force_vs_amplitude", "preload_study", "spread_study", "TiltingHemisphere",
    "with_hemisphere", "SMALL_LOOP_BYTES", "fast_cpu_loops", "device_side_gpu_loops",
    "use_compilation_cache",
    "DEFAULT_ZBA_RATIO", "FRICTION_LAWS", "LawParameter", "friction_law_name",
    "register_friction_law",
]
