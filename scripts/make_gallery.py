"""Make the README gallery: figures the tool draws, written to docs/gallery/.

    .venv/bin/python scripts/make_gallery.py [--out docs/gallery] [--skip-diagnosis]

1. model_tour.png: scanning vs stepping at 100 Hz, and z / friction force through a
   stepping period (the default profile, the paper's actuator);
2. velocity_map.png: `stickslip sweep` heat map over amplitude x frequency x direction;
3. zba_surface.png: z_ba per recording of a grid (one vmapped solve) and the surface;
4. diagnosis.png: the residual of a concealed-effect set before and after
   `diagnose` named and added the missing physics (about 3 min on two cores).
"""

import argparse
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.plots import save_figure, subplots  # noqa: E402
from stickslip_jax.sweep.zba_surface import plot_zba_surface  # noqa: E402
from stickslip_jax.synthetic import with_drive_dependent_zba  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

ROOT = Path(__file__).resolve().parent.parent


def model_tour(path: Path) -> None:
    act = ss.lu2015_slc1720()
    fig, axes = subplots(1, 2, figsize=(11, 3.8))
    for amplitude, direction in ((20.0, "forward"), (40.0, "forward"), (60.0, "forward"),
                                 (60.0, "backward")):
        t, u = ss.sawtooth(amplitude, 100.0, direction=direction, duration_s=0.05)
        drive = ss.DriveContext.make(backward=direction == "backward", amplitude=amplitude,
                                     frequency=100.0)
        q = np.asarray(ss.simulate(act, u, dt=t[1] - t[0], drive=drive))
        axes[0].plot(t * 1e3, (q - q[0]) * 1e6, lw=0.9, label=f"{amplitude:.0f} V {direction}")
    axes[0].set_xlabel("t [ms]")
    axes[0].set_ylabel("q [µm]")
    axes[0].set_title("scanning (20 V) and stepping, 100 Hz sawtooth", fontsize=10)
    axes[0].legend(fontsize=7)
    t, u = ss.sawtooth(60.0, 100.0, direction="forward", duration_s=0.03)
    drive = ss.DriveContext.make(amplitude=60.0, frequency=100.0)
    fs = 1 / (t[1] - t[0])
    # A finer look: resimulate at 16x the sample rate for a smooth edge.
    t_f, u_f = ss.sawtooth(60.0, 100.0, direction="forward", duration_s=0.03,
                           sample_rate_Hz=16 * fs)
    tr = ss.simulate_states(act, u_f, dt=t_f[1] - t_f[0], drive=drive, substeps=4)
    sel = (t_f >= 0.02 - 0.2e-3) & (t_f <= 0.02 + 2.5e-3)
    tp = (t_f[sel] - 0.02) * 1e3
    zba = float(act.friction.z_ba(drive))
    zss = float(act.friction.zss_magnitude(0.0, drive))
    axes[1].plot(tp, np.asarray(tr.z)[sel] * 1e6, label="z [µm]")
    for level, name in ((zba, "z_ba"), (zss, "|z_ss|")):
        axes[1].axhline(-level * 1e6, color="grey", ls="--", lw=0.7)
        axes[1].text(tp[-1], -level * 1e6, f" −{name}", fontsize=7, va="center")
    ax_f = axes[1].twinx()
    ax_f.plot(tp, np.asarray(tr.friction)[sel], color="C1", lw=0.9)
    ax_f.set_ylabel("friction force Ff [N]", color="C1")
    axes[1].set_ylabel("friction state z [µm]", color="C0")
    axes[1].set_xlabel("time after the abrupt edge [ms]")
    axes[1].set_title("60 V stepping: at the edge z runs to −|z_ss| (slip), then sticks",
                      fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def velocity_map(path: Path) -> None:
    grid = ss.DriveGrid.make(np.linspace(10, 80, 15), np.array([50, 100, 200, 500, 1000.0]),
                             "both")
    vm = ss.velocity_map(ss.lu2015_slc1720(), grid, periods=10)
    save_figure(vm.plot(), path)


def zba_surface(path: Path) -> None:
    base = ss.lu2015_slc1720()
    truth = with_drive_dependent_zba(base)  # z_ba: example_zba (tanh x sqrt)
    specs = [ss.DriveSpec("sawtooth", a, fr, d, 4 / fr) for d in ("forward", "backward")
             for a in (40.0, 50.0, 60.0, 70.0, 80.0) for fr in (50.0, 150.0, 400.0, 1000.0)]
    recs = ss.simulate_set(truth, specs, noise_m=1e-9, seed=11)
    points = ss.fit_zba_points(base, recs)
    save_figure(plot_zba_surface(points, ss.fit_zba_surface(points)), path)


def diagnosis(path: Path) -> None:
    from stickslip_jax.diagnose.locate import residual_of

    folder = ROOT / "fixtures" / "concealed" / "set_05"
    keep = {"step_40V", "sine_40V_50Hz", "saw_20V_100Hz_fwd", "saw_60V_100Hz_fwd",
            "saw_60V_100Hz_bwd", "saw_60V_500Hz_fwd", "saw_60V_500Hz_bwd"}
    recs = [r for r in ss.load_recordings(folder) if r.name in keep]
    init = ss.load_params(ROOT / "fixtures" / "identification" / "truth.json")
    d = ss.diagnose(recs, init=init, fix={"Ms": 0.0247}, identify_steps=(), max_rounds=1,
                    top=2, max_steps=20, size_at_most=3)
    i = int(np.argmax([a.chi2 for a in d.analyses_baseline]))
    rec = d.data.recordings[i]
    fig, axes = subplots(1, 2, figsize=(11, 3.8))
    sel = rec.time_s <= 6e-3
    for q, label in ((d.q_baseline[i], "paper's model"),
                     (d.q_final[i], " + ".join(c.name for c in d.accepted) or "final")):
        e = residual_of(rec, q)
        axes[0].plot(rec.time_s[sel] * 1e3, e[sel] * 1e9, lw=0.7, label=label)
    axes[0].set_xlabel("t [ms]")
    axes[0].set_ylabel("residual [nm]")
    axes[0].set_title(f"{rec.name}: residual, first 6 ms", fontsize=10)
    axes[0].legend(fontsize=7)
    names = [r.name for r in d.data.recordings]
    x = np.arange(len(names))
    axes[1].bar(x - 0.2, [a.chi2 for a in d.analyses_baseline], 0.4, label="paper's model")
    axes[1].bar(x + 0.2, [a.chi2 for a in d.analyses_final], 0.4, label="after diagnosis")
    axes[1].axhline(1.0, color="k", ls="--", lw=0.8)
    axes[1].set_yscale("log")
    axes[1].set_xticks(x, names, rotation=45, fontsize=6, ha="right")
    axes[1].set_ylabel("mean (residual / noise)²")
    axes[1].set_title(f"verdict: {d.verdict}; named: "
                      f"{', '.join(c.name for c in d.accepted) or 'nothing'}", fontsize=10)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "gallery")
    ap.add_argument("--skip-diagnosis", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = [("model_tour", model_tour), ("velocity_map", velocity_map),
            ("zba_surface", zba_surface)]
    if not args.skip_diagnosis:
        jobs.append(("diagnosis", diagnosis))
    for name, job in jobs:
        job(args.out / f"{name}.png")
        print("wrote", args.out / f"{name}.png")


if __name__ == "__main__":
    main()
