"""``stickslip contacts``: preload (CEIM), multi-contact spread and force generation."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .common import (
    check_amplitudes,
    check_frequencies,
    check_outputs,
    fail,
    load_actuator,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip contacts --out out/contacts

  stickslip contacts --params out/id/params.json --preloads 0.5,1,2,4 --spread lumped=1
  --spread equal=1,1,1,1,1,1 --spread uneven=6,5,4,2,1,1 --k-load 1e5 --out out/contacts

Three studies after Nguyen et al. 2012 (the second of the two papers the model follows:
preload-dependent friction, multi-contact runners), each a batched simulation: step per period vs
amplitude and the 0-amplitude threshold at several preloads (CEIM: z_ba and the
contact stiffness grow with the preload, so the step falls); the same for several
splits of the preload over the contacts of a multi-contact runner; the force
generated against a load spring vs amplitude, with the elasto-plastic dead zone and
LuGre (no dead zone) beside. A parameter set with another law (elasto-plastic, or any
with a break-away strain) is turned into a CEIM contact with its stiffness, break-away
strain and Coulomb level at --reference-preload (half of z_ba and of the stiffness
growing with the preload), and the output says so. Writes contacts.json and three
figures.
"""


def _spreads(items: list[str]) -> dict[str, list[float]]:
    out = {}
    for item in items:
        label, _, values = item.partition("=")
        try:
            shares = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            shares = []
        if not label or not shares or any(s <= 0 for s in shares):
            raise fail(f"--spread {item!r}: write LABEL=s1,s2,... with positive shares")
        out[label] = shares
    return out


def contacts_command(
    out: Path = typer.Option(..., "--out", help="Output folder."),
    params: Path | None = typer.Option(None, "--params", help="Parameters (JSON). Default: "
                                       "the lu2015_slc1720 profile."),
    preloads: str = typer.Option("0.5,1,2,4", "--preloads", help="Preloads [N] (list or "
                                 "a:b:n)."),
    reference_preload: float = typer.Option(1.0, "--reference-preload", help="Preload [N] "
                                            "at which a CEIM contact equals the "
                                            "elasto-plastic parameters."),
    spread: list[str] = typer.Option(["lumped=1", "equal=1,1,1,1,1,1", "uneven=6,5,4,2,1,1",
                                      "one-heavy=20,1,1,1,1,1"],
                                     "--spread", help="LABEL=shares of the normal force "
                                     "per contact (repeat)."),
    amplitudes: str = typer.Option("5:80:16", "--amplitudes", help="Amplitudes [V]."),
    frequency: float = typer.Option(200.0, "--frequency", help="Sawtooth frequency [Hz]."),
    k_load: float = typer.Option(1e5, "--k-load", help="Load spring for force generation "
                                 "[N/m] (stiff: a blocked runner)."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs."),
) -> None:
    """Preload dependence, multi-contact runners and force generation (Nguyen 2012)."""
    with reported_errors():
        setup_jax()
        import equinox as eqx
        import numpy as np

        from ..files import atomic_write_text
        from ..model.ceim import CEIMElastoPlastic
        from ..model.friction import LuGre
        from ..model.registry import friction_law_name
        from ..plausibility import check_actuator_plausible
        from ..staging import staged_folder
        from ..sweep import parse_values
        from ..sweep.contact_studies import (
            force_vs_amplitude,
            plot_force_curves,
            preload_study,
            spread_study,
        )

        try:
            loads = parse_values(preloads, name="--preloads")
            amps = parse_values(amplitudes, name="--amplitudes")
        except ValueError as err:
            raise fail(str(err)) from None
        if not (np.all(np.isfinite(loads) & (loads > 0)) and reference_preload > 0):
            raise fail("--preloads and --reference-preload must be positive numbers of N")
        check_amplitudes(amps, "--amplitudes")
        check_frequencies(frequency, "--frequency")
        if not k_load > 0:
            raise fail(f"--k-load {k_load:g}: the load spring must be positive [N/m]")
        spreads = _spreads(spread)
        paths = {n: out / n for n in ("contacts.json", "preload.png", "spread.png",
                                       "force.png")}
        check_outputs(dict.fromkeys(paths.values()), force=force, inputs=[params])
        # Locked before the studies, written whole or not at all (stickslip_jax.staging).
        with staged_folder(out, "contacts", force=force) as stage:
            act = load_actuator(params)
            check_actuator_plausible(act, params)
            notes = []
            fr = act.friction
            if isinstance(fr, CEIMElastoPlastic):
                ceim = fr
            else:
                try:
                    ceim = CEIMElastoPlastic.matching_law(fr, preload=reference_preload)
                except ValueError as err:
                    raise fail(f"the preload study needs a CEIM contact or one to make it "
                               f"from: {err}") from None
                notes.append(f"CEIM contact made from the '{friction_law_name(fr)}' parameters: "
                             f"the same stiffness, z_ba and Coulomb level at "
                             f"{reference_preload:g} N, half of z_ba and of the contact "
                             f"stiffness growing with the preload (illustrative coefficients, "
                             f"not identified)")
            act_ceim = eqx.tree_at(lambda a: a.friction, act, ceim)
            typer.echo("preload study...")
            pre = preload_study(act_ceim, loads, amps, frequency)
            pre.plot(stage / "preload.png", title=f"CEIM: step vs amplitude at {frequency:g} Hz "
                     f"for several preloads")
            typer.echo("contact spread study...")
            spr = spread_study(act_ceim, spreads, amps, frequency)
            spr.plot(stage / "spread.png", title=f"multi-contact runner (CEIM contacts, total "
                     f"{float(ceim.preload):g} N), {frequency:g} Hz")
            typer.echo("force generation...")
            fc = float(ceim.coulomb_force())
            lugre = eqx.tree_at(lambda a: a.friction, act, LuGre(
                float(ceim.sigma0()), 0.0, 0.0, fc, fc, 1e-3))
            law = friction_law_name(fr)
            label = "elasto-plastic" if law in ("elastoplastic", "ceim") else law
            curves = {label: force_vs_amplitude(act, amps, frequency, k_load=k_load),
                      "LuGre (same stiffness and Coulomb level)":
                          force_vs_amplitude(lugre, amps, frequency, k_load=k_load)}
            plot_force_curves(curves, stage / "force.png")
            payload = {"notes": notes, "preload_study": pre.to_dict(),
                       "spread_study": {**spr.to_dict(), "spreads": spreads},
                       "force_generation": {k: v.to_dict() for k, v in curves.items()}}
            atomic_write_text(stage / "contacts.json", json.dumps(payload, indent=1) + "\n")
    for note in notes:
        typer.echo(f"note: {note}")
    typer.echo("0-amplitude threshold by preload: " + ", ".join(
        f"{p:g} N: {t:.1f} V" for p, t in zip(pre.settings, pre.thresholds_V, strict=True)))
    typer.echo("by contact spread: " + ", ".join(
        f"{s}: {t:.1f} V" for s, t in zip(spr.settings, spr.thresholds_V, strict=True)))
    for label, c in curves.items():
        dz = c.dead_zone_V()
        zone = (f"dead zone below {dz:.1f} V" if dz > c.amplitudes_V.min() else
                f"no dead zone down to {c.amplitudes_V.min():g} V")
        typer.echo(f"force generation, {label}: max {1e3 * np.max(c.force_N):.1f} mN, {zone}")
    typer.echo(f"wrote {', '.join(str(p) for p in paths.values())}")
