"""Every figure the commands write opens as an image of a useful size that is not blank,
and says what issue #67 asked of it (legends inside the axes and naming every trace, a
symmetric-log velocity scale with the scanning cells marked, no axis offset and a
"flat within uncertainty" statement on the z_ba surface, the noise floor on the PSDs,
the hysteresis lag explained, distinct styles on coinciding curves, labelled axes).

One test per command that draws: simulate, identify, sweep, zba-surface, contacts and
diagnose (``drive`` writes no figure, only text and JSON). Commands are run in-process
through the CLI where one small run is cheap; identify and diagnose would take minutes,
so their figure-writing functions are called directly on real recordings from
fixtures/ with models simulated from the identification truth.
"""

import csv
import importlib
import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app

IDENT = Path(__file__).resolve().parent.parent / "fixtures" / "identification"
REF = Path(__file__).resolve().parent.parent / "fixtures" / "reference"


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def assert_png_readable(path, *, min_width: int = 400, min_height: int = 300) -> np.ndarray:
    """``path`` is a PNG of at least ``min_width`` x ``min_height`` pixels that is not
    blank: its pixel values vary, it holds many distinct colours, and a visible share
    of it differs from its background. Returns the pixels (rows, columns, channels)."""
    import matplotlib.image as mpimg

    path = Path(path)
    assert path.is_file(), f"{path} was not written"
    assert path.stat().st_size > 0, f"{path} is empty"
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[2] in (3, 4), f"{path}: not an RGB(A) image"
    h, w = img.shape[:2]
    assert w >= min_width and h >= min_height, f"{path}: {w}x{h} pixels"
    rgb = img[..., :3].reshape(-1, 3)
    assert float(rgb.std()) > 0.02, f"{path}: blank (pixel std {rgb.std():.4f})"
    colours, counts = np.unique(np.round(rgb * 255).astype(np.uint8), axis=0,
                                return_counts=True)
    assert len(colours) > 16, f"{path}: only {len(colours)} distinct colour(s)"
    background = counts.max() / counts.sum()
    assert background < 0.99, f"{path}: {100 * background:.1f} % is one colour"
    return img


def test_assert_png_readable_rejects_missing_small_and_blank_images(tmp_path):
    import matplotlib.image as mpimg

    with pytest.raises(AssertionError, match="not written"):
        assert_png_readable(tmp_path / "missing.png")
    mpimg.imsave(tmp_path / "blank.png", np.ones((400, 600, 3)))
    with pytest.raises(AssertionError, match="blank"):
        assert_png_readable(tmp_path / "blank.png")
    noise = np.random.default_rng(0).random((100, 600, 3))
    mpimg.imsave(tmp_path / "small.png", noise)
    with pytest.raises(AssertionError, match="600x100"):
        assert_png_readable(tmp_path / "small.png")
    mpimg.imsave(tmp_path / "ok.png", np.resize(noise, (400, 600, 3)))
    assert assert_png_readable(tmp_path / "ok.png").shape[:2] == (400, 600)


def drawn(fig):
    """``fig`` drawn (Agg), so that the extents of its artists are final."""
    FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig


def legend_texts(ax) -> list[str]:
    leg = ax.get_legend()
    return [] if leg is None else [t.get_text() for t in leg.get_texts()]


def assert_legends_inside_axes(fig):
    """Every legend lies within its axes (to a pixel), so none runs off the figure."""
    drawn(fig)
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        box, frame = leg.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert (box.x0 >= frame.x0 - 1 and box.x1 <= frame.x1 + 1
                and box.y0 >= frame.y0 - 1 and box.y1 <= frame.y1 + 1), \
            f"legend {legend_texts(ax)} outside its axes"


def assert_axes_labelled(fig, *, categorical=()):
    """Every axes (but colorbars) has x and y labels, with a unit ``[...]`` unless the
    label is one of ``categorical`` (an axis of names, e.g. one bar per recording)."""
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            assert label, f"axes {ax.get_title()!r}: an axis without a label"
            assert label in categorical or re.search(r"\[.+\]", label), \
                f"axes {ax.get_title()!r}: label {label!r} without a unit"


# -------------------------------------------------------------------------- simulate
def test_simulate_figures_name_every_trace_inside_the_axes(tmp_path):
    from stickslip_jax.plots import plot_trace

    res = run("simulate", "--duration", 0.02, "--out", tmp_path / "a.csv", "--plot",
              tmp_path / "trace.png")
    assert res.exit_code == 0, res.output
    assert_png_readable(tmp_path / "trace.png")
    src = REF / "ref_saw_50V_100Hz_fwd.csv"
    res = run("simulate", "--params", REF / "params.json", "--voltage-from", src, "--out",
              tmp_path / "b.csv", "--plot", tmp_path / "SIM.png")
    assert res.exit_code == 0, res.output
    assert_png_readable(tmp_path / "SIM.png")

    rec, sim = ss.load_recording(src), ss.load_recording(tmp_path / "b.csv")
    alone = plot_trace(rec.time_s, rec.voltage_V, sim.position_m)
    compared = plot_trace(rec.time_s, rec.voltage_V, sim.position_m,
                          q_meas_m=rec.position_m, meas_label=f"recorded in {src.name}")
    for fig in (alone, compared):
        assert_legends_inside_axes(fig)
        for ax in fig.axes:  # a legend in every panel, naming every trace drawn
            named = [line.get_label() for line in ax.get_lines()
                     if not line.get_label().startswith("_")]
            assert named and set(named) <= set(legend_texts(ax)), (named, legend_texts(ax))
    assert any("simulated" in t for t in legend_texts(alone.axes[1]))


# -------------------------------------------------------------------------- identify
@pytest.fixture(scope="module")
def identified():
    """A result as :func:`write_figures` reads it: five fixture recordings (step, sine,
    the two Fig. 11 sawtooths and a backward one) with the truth's simulated outputs."""
    from stickslip_jax.identify.dataset import Dataset
    from stickslip_jax.simulate import simulate_recordings

    names = ("step_40V", "sine_40V_50Hz", "saw_20V_500Hz_fwd", "saw_40V_50Hz_fwd",
             "saw_40V_50Hz_bwd")
    recs = [ss.load_recording(IDENT / f"{n}.csv") for n in names]
    act = ss.load_params(IDENT / "truth.json")
    qs = simulate_recordings(act, recs)
    q = np.zeros((len(recs), max(r.n for r in recs)))
    for i, x in enumerate(qs):
        q[i, : x.size] = x
    nrmse = np.array([np.std(x - r.position_m) / np.ptp(r.position_m)
                      for x, r in zip(qs, recs, strict=True)])
    return SimpleNamespace(data=Dataset.from_recordings(recs), q_sim=q, nrmse=nrmse,
                           actuator=act)


def test_identify_figures_show_the_noise_floor_and_explain_the_loop(identified, tmp_path):
    from stickslip_jax.identify.figures import plot_hysteresis_loop, plot_psd_overlay
    from stickslip_jax.identify.report import FIGURES, write_figures
    from stickslip_jax.noise import noise_sigma

    out = write_figures(identified, tmp_path)
    for name in FIGURES:
        assert_png_readable(tmp_path / name)
    recs = identified.data.recordings
    for rec in recs:
        assert out[f"overlay_{rec.name}"] == tmp_path / f"overlay_{rec.name}.png"
        assert_png_readable(tmp_path / f"overlay_{rec.name}.png")

    saws = [r for r in recs if r.name in ("saw_20V_500Hz_fwd", "saw_40V_50Hz_fwd")]
    sims = [identified.q_sim[recs.index(r), : r.n] for r in saws]
    fig = plot_psd_overlay(saws, sims, title="t")
    for ax, rec in zip(fig.axes, saws, strict=True):
        assert "[m²/Hz]" in ax.get_ylabel()
        assert any("noise floor" in t for t in legend_texts(ax))
        floor = [line for line in ax.get_lines() if "noise floor" in line.get_label()][0]
        assert floor.get_ydata()[0] == pytest.approx(2 * noise_sigma(rec) ** 2 * rec.dt)

    sine = recs[1]
    fig = plot_hysteresis_loop(identified.actuator, sine, identified.q_sim[1, : sine.n])
    ax = fig.axes[0]
    assert any("q = 2Γ" in t for t in legend_texts(ax))
    note = " ".join(t.get_text() for t in ax.texts)
    assert "lags" in note and "τ" in note
    assert_legends_inside_axes(fig)


def test_identify_figures_are_the_same_files_with_a_helper_process(identified, tmp_path):
    from stickslip_jax.figure_helper import FigureHelper
    from stickslip_jax.identify.report import write_figures

    alone = write_figures(identified, tmp_path / "alone")
    with FigureHelper() as helper:
        shared = write_figures(identified, tmp_path / "shared", helper=helper)
    assert list(shared) == list(alone) and len(alone) == 9  # 5 overlays and 4 others
    for key, path in alone.items():
        assert shared[key] == tmp_path / "shared" / path.name
        assert shared[key].read_bytes() == path.read_bytes(), key


def test_display_psd_puts_white_noise_at_the_one_sided_level_either_way():
    from stickslip_jax.identify.figures import display_psd

    sigma, dt = 1e-9, 4e-5
    x = sigma * np.random.default_rng(1).standard_normal(20_000)
    for period in (None, 250.0):  # one periodogram (a step), Welch (a periodic drive)
        _, level = display_psd(x, dt, period_samples=period)
        assert np.mean(level) == pytest.approx(2 * sigma**2 * dt, rel=0.1)


@pytest.mark.parametrize(("n", "seg"), [(1250, 250), (2500, 625), (1001, 333), (999, 400)])
def test_welch_psd_is_scipys_welch(n, seg):
    from scipy.signal import welch

    from stickslip_jax.identify.figures import welch_psd

    # A random walk on a trend: the linear detrend and the one-sided doubling both show.
    x = np.random.default_rng(n).standard_normal(n).cumsum() + 0.01 * np.arange(n)
    f_ref, p_ref = welch(x, fs=1 / 2e-5, window="hann", nperseg=seg, noverlap=seg // 2,
                         detrend="linear")
    f, p = welch_psd(x, 2e-5, seg)
    np.testing.assert_allclose(f, f_ref, rtol=0, atol=0)
    np.testing.assert_allclose(p, p_ref, rtol=1e-12, atol=1e-14 * p_ref.max())


# ----------------------------------------------------------------------------- sweep
def test_sweep_figure_uses_a_symlog_scale_and_marks_scanning(tmp_path):
    from matplotlib.collections import QuadMesh
    from matplotlib.colors import SymLogNorm

    from stickslip_jax.sweep.grid import DriveGrid
    from stickslip_jax.sweep.map import VelocityMap
    from stickslip_jax.sweep.velocity import PointVelocity

    res = run("sweep", "--amplitudes", "15,40,70", "--frequencies", "50,500", "--periods", 3,
              "--settle", 1, "--out", tmp_path)
    assert res.exit_code == 0, res.output
    assert_png_readable(tmp_path / "velocity_map.png")

    rows = list(csv.DictReader((tmp_path / "velocity_map.csv").open()))
    grid = DriveGrid(np.array([float(r["amplitude_V"]) for r in rows]),
                     np.array([float(r["frequency_Hz"]) for r in rows]),
                     np.array([r["direction"] == "backward" for r in rows]))
    points = [PointVelocity(float(r["velocity_um_s"]) * 1e-6, float(r["step_nm"]) * 1e-9,
                            1e-6, r["regime"], np.zeros(1)) for r in rows]
    assert any(p.regime == "scanning" for p in points), "15 V should scan"
    fig = VelocityMap(grid, points, 3, 1, 25_000.0, None).plot()
    panels = [ax for ax in fig.axes if ax.get_title() in ("forward", "backward")]
    assert len(panels) == 2
    meshes = [c for ax in panels for c in ax.collections if isinstance(c, QuadMesh)]
    assert meshes and all(isinstance(m.norm, SymLogNorm) for m in meshes)
    assert any("µm/s" in ax.get_ylabel() for ax in fig.axes)  # the colour bars
    assert any("scanning" in t.get_text() for leg in fig.legends for t in leg.get_texts())
    assert any(p.get_hatch() for ax in panels for p in ax.patches)


# ----------------------------------------------------------------------- zba-surface
def _points(amps, freqs, backward, z, se):
    from stickslip_jax.sweep.zba_surface import ZbaPoints

    n = len(amps)
    return ZbaPoints([f"r{i}" for i in range(n)], np.asarray(amps, float),
                     np.asarray(freqs, float), np.asarray(backward, bool),
                     np.asarray(z, float), np.asarray(se, float), np.zeros(n),
                     np.ones(n, bool), np.ones(n, bool))


def test_zba_surface_figure_has_plain_axes_and_says_when_it_is_flat(tmp_path):
    from stickslip_jax.sweep.zba_surface import fit_zba_surface, plot_zba_surface

    data = [IDENT / f"saw_{a}V_{f}Hz_{d}.csv" for d in ("fwd", "bwd")
            for a, f in ((40, 50), (60, 50), (40, 500))]
    res = run("zba-surface", *data, "--params", IDENT / "truth.json", "--out", tmp_path)
    assert res.exit_code == 0, res.output
    assert_png_readable(tmp_path / "zba_surface.png")

    # A constant z_ba (within the standard errors) is said to be flat, drawn as one
    # level; a real slope keeps its surface. No axis offset label either way.
    rng = np.random.default_rng(4)
    amps, freqs = [40, 60, 80, 40, 60, 80], [50, 50, 50, 500, 500, 500]
    se = np.full(6, 1e-11)
    flat = _points(amps * 2, freqs * 2, [False] * 6 + [True] * 6,
                   np.r_[0.42e-6 + se * rng.standard_normal(6),
                         0.48e-6 + 0.01e-6 * (np.array(amps) - 60) / 20], np.r_[se, se])
    fig = drawn(plot_zba_surface(flat, fit_zba_surface(flat)))
    forward, backward = fig.axes
    assert "flat within uncertainty" in forward.get_title()
    said = re.search(r"z_ba = ([0-9.]+) ± ([0-9.]+) µm", forward.get_title())
    assert said, forward.get_title()
    assert float(said[1]) == pytest.approx(0.42, abs=3 * float(said[2]) + 1e-7)
    assert "flat" not in backward.get_title()
    surface = [[line for line in ax.get_lines() if line.get_label().startswith("surface")]
               for ax in (forward, backward)]
    assert not surface[0] and surface[1]  # the surface is drawn only where it is not flat
    for ax in fig.axes:
        assert ax.yaxis.get_offset_text().get_text() == ""
        assert "[µm]" in ax.get_ylabel() and "[V]" in ax.get_xlabel()


# -------------------------------------------------------------------------- contacts
def test_contacts_figures_read_as_units_and_keep_coinciding_curves_apart(tmp_path):
    from stickslip_jax.sweep.contact_studies import StepCurves
    from stickslip_jax.sweep.threshold import plot_ratio_study

    res = run("contacts", "--out", tmp_path, "--amplitudes", "10:60:3", "--preloads", "0.5,2",
              "--spread", "lumped=1", "--spread", "equal=1,1,1")
    assert res.exit_code == 0, res.output
    for name in ("preload.png", "spread.png", "force.png"):
        assert_png_readable(tmp_path / name)

    study = json.loads((tmp_path / "contacts.json").read_text())["preload_study"]
    curves = StepCurves(study["varied"], [c["setting"] for c in study["curves"]],
                        np.array(study["amplitudes_V"]),
                        np.array([c["step_nm"] for c in study["curves"]]) * 1e-9,
                        np.array([np.nan if c["threshold_V"] is None else c["threshold_V"]
                                  for c in study["curves"]]), study["frequency_Hz"])
    labels = legend_texts(curves.plot().axes[0])
    assert labels[0].startswith("preload 0.5 N") and labels[1].startswith("preload 2 N")
    assert not any("[N]" in t for t in labels)

    # Two curves that coincide: told apart by style, and said to coincide.
    steps = np.array([0.0, 0.0, 1e-7, 4e-7])
    same = StepCurves("contacts", ["lumped", "equal"], np.array([10.0, 20, 30, 40]),
                      np.array([steps, steps]), np.array([25.0, 25.0]), 200.0)
    ax = same.plot().axes[0]
    lumped, equal = [line for line in ax.get_lines() if not line.get_label().startswith("_")]
    assert (lumped.get_linestyle(), lumped.get_marker()) != (equal.get_linestyle(),
                                                             equal.get_marker())
    assert "= lumped" in legend_texts(ax)[1]
    ax = plot_ratio_study(same.amplitudes_V, {0.5: (steps, 25.0), 0.667: (steps, 25.0)},
                          frequency_Hz=200.0).axes[0]
    assert "= z_ba/z_ss = 0.5" in legend_texts(ax)[1]
    assert ax.get_lines()[0].get_linestyle() != ax.get_lines()[2].get_linestyle()


# -------------------------------------------------------------------------- diagnose
def test_diagnose_figures_have_units_and_legends(tmp_path, monkeypatch):
    """The three figures of ``stickslip diagnose`` on a small real diagnosis: recordings
    simulated with a sensor delay and 1 nm noise, the truth without it as the
    baseline, and with it as the final model (what a diagnosis naming it ends with)."""
    from stickslip_jax.diagnose.locate import analyse_recording
    from stickslip_jax.diagnose.report import (
        plot_overlays,
        plot_residual_map,
        plot_residual_psd,
    )
    from stickslip_jax.diagnose.results import Diagnosis, Verdict
    from stickslip_jax.identify.dataset import Dataset
    from stickslip_jax.noise import noise_sigma
    from stickslip_jax.simulate import simulate_recordings
    from stickslip_jax.synthetic import paper_protocol
    from stickslip_jax.testing.concealed import with_effect

    base = ss.load_params(IDENT / "truth.json")
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.02, sine_periods=1)
    drives = [s.recording(25_000.0) for s in specs]
    q_final = simulate_recordings(with_effect(base, "sensor_delay"), drives)
    q_base = simulate_recordings(base, drives)
    rng = np.random.default_rng(0)
    recs = [r.with_position_m(q + 1e-9 * rng.standard_normal(q.shape), unit="um")
            for r, q in zip(drives, q_final, strict=True)]
    sigmas = np.array([noise_sigma(r) for r in recs])
    before = [analyse_recording(r, q, s) for r, q, s in zip(recs, q_base, sigmas, strict=True)]
    after = [analyse_recording(r, q, s) for r, q, s in zip(recs, q_final, sigmas, strict=True)]
    d = Diagnosis(
        data=Dataset.from_recordings(recs), sigmas=sigmas, baseline=base, final=base,
        nrmse_baseline=np.array([a.nrmse for a in before]),
        nrmse_final=np.array([a.nrmse for a in after]),
        chi2_baseline=float(np.mean([a.chi2 for a in before])),
        chi2_final=float(np.mean([a.chi2 for a in after])),
        analyses_baseline=before, analyses_final=after, mismatch=[], accepted=[],
        rounds=[], not_testable={}, unexplained=None, verdict=Verdict.AUGMENTED,
        q_baseline=q_base, q_final=q_final, terms=[], timings={})
    assert d.chi2_baseline > 10 > 2 > d.chi2_final  # the figures have something to show

    # Keep each figure the functions make, to read its labels after it is written.
    # (By module path: the package attribute ``stickslip_jax.diagnose`` is the function.)
    report = importlib.import_module("stickslip_jax.diagnose.report")

    figs = []
    make = report.subplots

    def keep(*args, **kwargs):
        fig, axes = make(*args, **kwargs)
        figs.append(fig)
        return fig, axes

    monkeypatch.setattr(report, "subplots", keep)
    for name, fn in (("residual_map", plot_residual_map), ("overlays", plot_overlays),
                     ("residual_psd", plot_residual_psd)):
        fn(d, tmp_path / f"{name}.png")
        assert_png_readable(tmp_path / f"{name}.png")
    assert len(figs) == 3
    for fig in figs:  # every axes labelled with its unit, legends present
        assert_axes_labelled(fig, categorical=("recording (regime)",))
        assert any(legend_texts(ax) for ax in fig.axes)
    overlays = figs[1]
    assert all(legend_texts(ax) for ax in overlays.axes[len(overlays.axes) // 2:])


def test_save_figure_crops_a_png_to_its_ink_as_tight_does(tmp_path):
    # A figure with wide default margins: the saved PNG is cropped to what it draws plus
    # the pad, to within a few pixels of the artists' extents ("tight"), and keeps the
    # pad of white around its ink.
    from PIL import Image

    from stickslip_jax.plots import SAVE_DPI, SAVE_PAD_INCHES, save_figure, subplots

    def figure():
        fig, ax = subplots(figsize=(8, 6))
        fig.subplots_adjust(left=0.3, right=0.6, bottom=0.3, top=0.6)
        ax.plot([0, 1], [0, 1], label="a line")
        ax.set_xlabel("x [m]")
        ax.legend()
        return fig

    inked = np.asarray(Image.open(save_figure(figure(), tmp_path / "ink.png")))
    fig = figure()
    fig.savefig(tmp_path / "tight.png", dpi=SAVE_DPI, bbox_inches="tight",
                pad_inches=SAVE_PAD_INCHES)
    tight = np.asarray(Image.open(tmp_path / "tight.png"))
    assert inked.shape[1] < 0.5 * 8 * SAVE_DPI  # cropped from the full width
    np.testing.assert_allclose(inked.shape[:2], tight.shape[:2], atol=6)
    pad = int(SAVE_PAD_INCHES * SAVE_DPI)
    ink = np.any(inked[..., :3] != 255, axis=2)
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    assert rows[0] == cols[0] == pad
    assert inked.shape[0] - 1 - rows[-1] == inked.shape[1] - 1 - cols[-1] == pad


def test_save_figure_keeps_what_runs_off_the_canvas(tmp_path):
    # A label placed beyond the figure's right edge: ink reaches the canvas's edge, so the
    # crop is the artists' extents, which take in the whole label (as "tight" does).
    from PIL import Image

    from stickslip_jax.plots import SAVE_DPI, save_figure, subplots

    fig, ax = subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1])
    fig.text(0.9, 0.5, "a label that runs off the edge of the figure")
    inked = np.asarray(Image.open(save_figure(fig, tmp_path / "off.png")))
    assert inked.shape[1] > 4 * SAVE_DPI + 100
