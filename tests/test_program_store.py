"""Traced programs kept on disk (stickslip_jax.program_store): a later process reads the
program instead of tracing it, and computes the same numbers to the last bit."""

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax import program_store
from stickslip_jax.identify import sensitivities
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.residuals import dataset_plan
from stickslip_jax.program_store import stored_jit, use_program_store
from stickslip_jax.synthetic import paper_protocol, simulate_set

TRUTH = Path(__file__).resolve().parent.parent / "fixtures" / "identification" / "truth.json"


@pytest.fixture
def store(tmp_path):
    before = program_store.program_store_dir()
    assert use_program_store(tmp_path / "programs")
    yield tmp_path / "programs"
    use_program_store(before)


TRACES = []


def scaled_sum(x, scale, power: int):
    TRACES.append(power)  # runs only while tracing
    return scale * jnp.sum(x**power), x * scale


def fresh():
    """The function as a new process sees it: nothing in memory."""
    return stored_jit(scaled_sum)


def test_a_second_process_reads_the_program_and_gets_the_same_bits(store):
    x = np.linspace(0.1, 2.0, 7)
    expected = jax.jit(scaled_sum, static_argnums=2)(x, 1.3, 3)
    TRACES.clear()
    first = fresh()(x, jnp.asarray(1.3), 3)
    assert TRACES == [3]  # traced once (exported)
    assert len(list(store.glob("*.bin"))) == 1
    again = fresh()(x, jnp.asarray(1.3), 3)
    assert TRACES == [3]  # read, not traced
    for a, b, c in zip(jax.tree.leaves(expected), jax.tree.leaves(first),
                       jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))


def test_static_values_and_shapes_key_the_program(store):
    f = fresh()
    f(np.ones(3), 2.0, 2)
    f(np.ones(3), 2.0, 3)  # another static value
    f(np.ones(4), 2.0, 2)  # another shape
    f(np.ones(3, dtype=np.float32), 2.0, 2)  # another dtype
    assert len(list(store.glob("*.bin"))) == 4
    assert float(f(np.ones(3), 2.0, 3)[0]) == 6.0


def scaled_by(x, scale):
    return x * scale.k if hasattr(scale, "k") else x * scale()


def test_arguments_that_cannot_be_keyed_across_processes_are_traced_as_before(store):
    class OwnScale:  # a type outside the package: it may change without its source
        k = 3.0

    f = stored_jit(scaled_by)
    assert float(f(jnp.asarray(2.0), OwnScale())) == 6.0
    assert float(f(jnp.asarray(2.0), lambda: 4.0)) == 8.0  # its text names an address
    assert list(store.glob("*.bin")) == []


def test_a_process_whose_source_was_edited_stores_nothing(store, monkeypatch):
    monkeypatch.setattr(program_store, "_digest", lambda: "edited since the import")
    out = fresh()(np.ones(3), 2.0, 2)
    assert float(out[0]) == 6.0
    assert list(store.glob("*.bin")) == []


def test_threads_asking_for_one_new_program_trace_it_once(store):
    from concurrent.futures import ThreadPoolExecutor

    f = fresh()
    TRACES.clear()
    with ThreadPoolExecutor(4) as pool:
        outs = list(pool.map(lambda _: f(np.arange(4.0), 0.5, 2), range(8)))
    assert TRACES == [2] and len(list(store.glob("*.bin"))) == 1
    assert all(float(o[0]) == 7.0 for o in outs)  # 0.5·(0 + 1 + 4 + 9)


def test_a_damaged_program_is_traced_again_and_replaced(store):
    fresh()(np.ones(3), 2.0, 2)
    (path,) = store.glob("*.bin")
    path.write_bytes(b"not a program")
    TRACES.clear()
    out = fresh()(np.ones(3), 2.0, 2)
    assert float(out[0]) == 6.0 and TRACES == [2]
    assert path.stat().st_size > 100


def test_inside_a_transformation_it_is_the_plain_program(store):
    f = fresh()
    grad = jax.grad(lambda s: f(np.arange(3.0), s, 2)[0])(1.5)
    assert float(grad) == 5.0  # d/ds s·(0 + 1 + 4)
    assert list(store.glob("*.bin")) == []


def test_the_oldest_programs_go_past_the_size_limit(tmp_path):
    import os

    for i in range(5):
        p = tmp_path / f"{i}.bin"
        p.write_bytes(b"x" * 1000)
        os.utime(p, (i, i))
    program_store._evict(tmp_path, limit=3000)
    assert sorted(p.name for p in tmp_path.glob("*.bin")) == ["3.bin", "4.bin"]


def _two_recordings():
    """``(actuator, plan, mask, programs)``: the truth, two short recordings of it, and
    their shared programs carrying Mp, Kp and rho0 (one thread)."""
    base = ss.load_params(TRUTH)
    specs = paper_protocol(periods=1, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.005, sine_periods=1)
    data = Dataset.from_recordings(simulate_set(base, specs[:2], noise_m=1e-9, seed=1))
    mask = sensitivities.perturbed_mask(base, ["Mp", "Kp", "rho0"])
    return (base, dataset_plan(base, data), mask,
            sensitivities.RecordingPrograms(data, base, mask, threads=1))


def _two_tangents(base, mask):
    """Two tangents along the mask's leaves: all ones, all twos."""
    return jax.tree.map(lambda x: np.stack([np.ones(np.shape(x)), 2 * np.ones(np.shape(x))]),
                        eqx.filter(base, mask))


def test_the_simulators_programs_are_the_traced_ones_to_the_bit(store):
    """A recording's trace and its derivatives along two tangents through the stored
    program equal equinox.filter_jit's to the last bit, compiled in this process and
    read back from the store as another process would."""
    base, plan, mask, programs = _two_recordings()
    tangents = _two_tangents(base, mask)
    stored = programs.sensitivities(base, tangents, plan)
    kept = sorted(store.glob("*.bin"))  # the planning's and the recordings' programs
    assert kept
    use_program_store(None)
    traced = programs.sensitivities(base, tangents, plan)
    use_program_store(store)
    for a, b in zip(stored, traced, strict=True):
        np.testing.assert_array_equal(a, b)
    # Read from the store: a new wrapper of the same function has nothing in memory.
    perturbed, fixed = eqx.partition(base, mask)
    perturbed = jax.tree.map(lambda x: jnp.asarray(x, dtype=float), perturbed)
    w = sensitivities.tangents_per_call(2, programs.width)  # as sensitivities() pads
    share = jax.tree.map(lambda x: np.concatenate([x, np.zeros((w - 2,) + x.shape[1:])]),
                         tangents)
    again = stored_jit(sensitivities._row_with_tangents.__wrapped__)(
        perturbed, fixed, share, *programs._rows[0], plan)
    np.testing.assert_array_equal(np.asarray(again[0]), traced[0][0])
    np.testing.assert_array_equal(np.asarray(again[1])[:, :2], traced[1][0])
    assert sorted(store.glob("*.bin")) == kept  # read, not made again


_SIMULATE = """
import sys, jax
from pathlib import Path
jax.config.update("jax_enable_x64", True)
import numpy as np
import stickslip_jax as ss
print(ss.use_compilation_cache(Path(sys.argv[1])))
u = 40.0 * np.sin(2 * np.pi * 500.0 * np.arange(200) / 25_000.0)
q = ss.simulate(ss.load_params(sys.argv[2]), u, dt=1 / 25_000.0)
print(np.asarray(q).tobytes().hex())
"""


def test_a_second_process_simulates_from_the_stored_program(tmp_path):
    """Two fresh processes sharing a cache folder: the first stores the simulation's
    program, the second reads it (adds none) and computes the same bits."""
    import subprocess
    import sys

    runs = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _SIMULATE, str(tmp_path), str(TRUTH)],
                             capture_output=True, text=True, check=True)
        runs.append(out.stdout.split())
        if len(runs) == 1:
            stored = sorted((tmp_path / "programs").glob("*.bin"))
            assert stored
    assert runs[0][0] == "True" and runs[0][1] == runs[1][1]
    assert sorted((tmp_path / "programs").glob("*.bin")) == stored


@pytest.fixture
def compiles():
    """The XLA compilations (backend compile events) made while the test runs."""
    events = []

    def listen(event, duration, **_):
        if "backend_compile" in event:
            events.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    yield events
    jax.monitoring.unregister_event_duration_listener(listen)


def test_a_precompiled_program_runs_without_compiling_again(store, compiles):
    x = np.linspace(0.1, 2.0, 7)
    expected = jax.jit(scaled_sum, static_argnums=2)(x, 1.3, 3)
    f = fresh()
    TRACES.clear()
    compiles.clear()
    assert f.precompile(x, jnp.asarray(1.3), 3)
    assert TRACES == [3] and compiles  # traced and compiled, not run
    compiles.clear()
    out = f(x, jnp.asarray(1.3), 3)
    assert compiles == [] and TRACES == [3]
    for a, b in zip(jax.tree.leaves(expected), jax.tree.leaves(out), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Another program of the same function is compiled by its call, as before.
    assert float(f(x, jnp.asarray(1.3), 2)[0]) == pytest.approx(1.3 * np.sum(x**2))
    assert compiles


def test_a_call_during_its_programs_precompiling_waits_for_it(store):
    import threading

    f = fresh()
    TRACES.clear()
    ready = threading.Thread(target=f.precompile, args=(np.arange(4.0), 0.5, 2))
    ready.start()
    outs = [f(np.arange(4.0), 0.5, 2) for _ in range(3)]
    ready.join()
    assert TRACES == [2] and len(list(store.glob("*.bin"))) == 1
    assert all(float(o[0]) == 7.0 for o in outs)


def test_without_a_store_nothing_is_precompiled():
    before = program_store.program_store_dir()
    use_program_store(None)
    try:
        assert fresh().precompile(np.ones(3), 2.0, 2) is False
    finally:
        use_program_store(before)


def test_prefetched_programs_give_the_traced_bits(store, compiles):
    """RecordingPrograms.prefetch compiles the wide program and the doubled plan's
    value-only one beside the caller; what they then give equals the traced programs'
    to the last bit."""
    base, plan, mask, programs = _two_recordings()
    assert programs.width == 3  # two tangents go in one call of the wide program
    thread = programs.prefetch(base, plan)
    tangents = _two_tangents(base, mask)
    thread.join()
    compiles.clear()
    fetched = programs.sensitivities(base, tangents, plan)
    doubled = programs.simulate(base, plan.doubled())
    assert compiles == []  # both programs were ready
    use_program_store(None)
    traced = programs.sensitivities(base, tangents, plan)
    np.testing.assert_array_equal(programs.simulate(base, plan.doubled()), doubled)
    use_program_store(store)
    for a, b in zip(fetched, traced, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_prefetch_without_the_wide_program_makes_only_the_error_estimates(
        store, compiles):
    """``prefetch(wide=False)``: the doubled plan's value-only program is ready, the
    wide one is left to its call (which compiles it); ``goes_wide`` says which columns
    counts run it (two of width 3 do, one does not)."""
    base, plan, mask, programs = _two_recordings()
    assert programs.goes_wide(2) and not programs.goes_wide(1)
    programs.prefetch(base, plan, wide=False).join()
    compiles.clear()
    programs.simulate(base, plan.doubled())
    assert compiles == []
    programs.sensitivities(base, _two_tangents(base, mask), plan)
    assert compiles


def test_identify_prefetches_the_wide_program_only_for_a_later_wide_jacobian(
        monkeypatch):
    """The first step's prefetch asks for the wide program when a later step's or the
    uncertainty's Jacobian has more than half the width in columns (the hysteresis
    step's PI weights, every fitted quantity), not for a dynamics step alone."""
    asked = []

    class Stop(Exception):
        pass

    def record(self, actuator, plan, *, wide=True):
        asked.append(wide)
        raise Stop  # the choice is all this test needs

    monkeypatch.setattr(sensitivities.RecordingPrograms, "prefetch", record)
    base = ss.load_params(TRUTH)
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.03, sine_periods=2)  # enough to determine
    recs = simulate_set(base, specs, noise_m=1e-9, seed=1)
    for steps, uncertainty in [(("dynamics",), False), (("dynamics",), True),
                               (("dynamics", "hysteresis"), False)]:
        with pytest.raises(Stop):
            ss.identify(recs, init=base, fix={"Ms": 0.0247}, steps=steps,
                        uncertainty=uncertainty, n_pi=6)
    assert asked == [False, True, True]


def test_background_jobs_end_with_the_one_running_at_exit(store):
    """At the interpreter's exit (``_finish_background``, an atexit hook) a prefetch
    thread finishes its job and starts no other; the hook returns once it has."""
    import threading

    started, release, ran = threading.Event(), threading.Event(), []

    def first():
        started.set()
        release.wait(10)
        ran.append("first")

    thread = sensitivities.in_background([first, lambda: ran.append("second")])
    assert started.wait(10)
    threading.Timer(0.2, release.set).start()
    sensitivities._finish_background()
    assert not thread.is_alive() and ran == ["first"]


def test_nothing_runs_in_the_background_without_a_store():
    before = program_store.program_store_dir()
    use_program_store(None)
    try:
        assert sensitivities.in_background([lambda: None]) is None
    finally:
        use_program_store(before)


def test_weak_and_strong_leaves_share_one_program(store, compiles):
    """An actuator whose float leaves are weakly typed (``jnp.asarray(0.5)``) and the
    same one with ordinary leaves run one value program and one tangent program, to the
    same bits: the programs are keyed by argument type, weak type included."""
    base, plan, mask, programs = _two_recordings()
    weak = jax.tree.map(lambda x: jnp.asarray(float(x)) if np.ndim(x) == 0 else x, base)
    assert any(getattr(x, "weak_type", False) for x in jax.tree.leaves(weak))
    tangents = _two_tangents(base, mask)
    q_strong = programs.simulate(base, plan)
    s_strong = programs.sensitivities(base, tangents, plan)
    compiles.clear()
    np.testing.assert_array_equal(programs.simulate(weak, plan), q_strong)
    for a, b in zip(programs.sensitivities(weak, tangents, plan), s_strong, strict=True):
        np.testing.assert_array_equal(a, b)
    assert compiles == []


def test_a_calls_key_sees_what_the_program_depends_on():
    """``_call_key``, made at every call from one flattening: its leaves are the ones
    ``equinox.partition`` gives the program, in the same order; keys differ where the
    program would (an array's place, shape, dtype or weak type; a static value) and
    agree where it would not (other values); a tracer has no key."""
    base = ss.load_params(TRUTH)
    args = (base, np.ones(3), 2, "a", (jnp.asarray(0.5), None, 1.5))
    key, leaves = program_store._call_key(args, "folder")
    expected = jax.tree.leaves(eqx.partition(args, eqx.is_array)[0])
    assert len(leaves) == len(expected) and all(
        a is b for a, b in zip(leaves, expected, strict=True))

    def key_of(*a):
        return program_store._call_key(a, "folder")[0]

    x = np.ones(3)
    assert key_of(x, 1.0) == key_of(2 * x, 1.0)  # values of arrays: the same program
    assert len({key_of(x, 1.0), key_of(1.0, x), key_of(x, 2.0), key_of(x, 1),
                key_of(np.ones(4), 1.0), key_of(x.astype(np.float32), 1.0),
                key_of(jnp.asarray(x), 1.0)}) == 6  # jnp ones(3) float64 = numpy's
    assert key_of(jnp.asarray(1.0), x) != key_of(jnp.asarray(1.0, dtype=float), x)  # weak
    assert program_store._call_key(args, "folder")[0] != program_store._call_key(
        args, "other")[0]
    seen = []
    jax.jit(lambda v: seen.append(program_store._call_key((v, 1.0), "f")) or v)(x)
    assert seen == [(None, None)]
