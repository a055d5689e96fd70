"""`crane-train info SESSION... [--json]`: what is in session files and how much of it is usable."""

from __future__ import annotations

import json

import click

from crane_io.cli_support import Number, cli_errors


def session_info(paths, joints=None, alpha: float = 0.1, arm: str = "follower") -> dict:
    """Per file: duration, rate, samples, joints; over all files: the preprocessed moving fractions."""
    from ..data.preprocess import PreprocessConfig, preprocess  # numpy, scipy, h5py: not for --help
    from ..data.session import hand_on, read_sessions

    sessions = read_sessions(paths, arm)
    config = PreprocessConfig(alpha=alpha, arm=arm, **({"joints": tuple(joints)} if joints else {}))
    ds = preprocess(sessions, config)
    files = [{"path": s.path, "source": s.source, "hand_on": hand_on(s.attrs, s.path),
              "excitation_arm": _excitation_arm(s.attrs), "rate_hz": s.rate_hz, "samples": len(s),
              "duration_s": s.duration_s, "joint_names": list(s.joint_names), "truncated": s.truncated,
              "complete": s.attrs.get("complete"), "recorded_velocity": s.dq is not None} for s in sessions]
    return {"files": files, "arm": arm, "joints": list(ds.joint_names), "samples_preprocessed": len(ds),
            "rate_hz_preprocessed": ds.rate_hz, "sigma_rad_s": ds.meta["sigma"], "alpha": alpha,
            "usable_fraction": ds.meta["usable_fraction"], "splits": _splits_need(ds),
            "data_checks": ds.meta["data_checks"]}


def _excitation_arm(attrs: dict) -> str | None:
    """The arm that ran an exciting trajectory on its own (`crane-collect excite`), None for other data."""
    from crane_io import session_format as sf

    if not bool(attrs.get(sf.EXCITATION_ATTR, False)):
        return None
    arm = attrs.get(sf.EXCITATION_ARM_ATTR, "follower")
    return arm.decode() if isinstance(arm, bytes) else str(arm)


def _splits_need(ds) -> dict:
    """How much data the default splits need for these joints (train.data.splits), against what there is."""
    from ..data.splits import SplitConfig, eval_fraction, needed_samples

    cfg = SplitConfig()
    mode = cfg.mode(len(ds.joint_names))
    need = needed_samples(cfg, eval_fraction(ds, mode), ds.rate_hz)
    return {"eval_set": mode, "need_samples": need, "need_s": need / ds.rate_hz,
            "have_s": len(ds) / ds.rate_hz}


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--joints", default="joint1,joint2,joint4", show_default=True,
              help="Comma-separated learning joints, or 'all' (every arm joint recorded).")
@click.option("--alpha", default=0.1, show_default=True, type=Number(float, 0),
              help="Dead-zone threshold factor.")
@click.option("--arm", type=click.Choice(["leader", "follower"]), default="follower", show_default=True,
              help="The arm whose data to describe.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@cli_errors
def info(sessions, joints, alpha, arm, as_json):
    """Duration, rate, samples and the fraction of samples in which joints move."""
    doc = session_info(sessions, [j.strip() for j in joints.split(",") if j.strip()], alpha, arm)
    if as_json:
        click.echo(json.dumps(doc, indent=2))
        return
    for f in doc["files"]:
        flag = "  (truncated: cut to the shortest dataset)" if f["truncated"] else ""
        what = (f"excitation data (the {f['excitation_arm']} alone)" if f["excitation_arm"]
                else f"hand on the {f['hand_on']}")
        click.echo(f"{f['path']}: {f['source']}, {f['duration_s']:.1f} s at {f['rate_hz']:g} Hz, "
                   f"{f['samples']} samples, {len(f['joint_names'])} joints, {what}{flag}")
    uf = doc["usable_fraction"]
    click.echo(f"preprocessed ({arm}): {doc['samples_preprocessed']} samples at "
               f"{doc['rate_hz_preprocessed']:g} Hz, "
               f"alpha {alpha:g}")
    for name, sigma in zip(doc["joints"], doc["sigma_rad_s"]):
        click.echo(f"  {name:<8} moving {uf['per_joint'][name]:6.1%}   sigma {sigma:.3f} rad/s")
    click.echo(f"  all joints moving {uf['all_joints']:6.1%}")
    checks = doc["data_checks"]
    click.echo(f"data checks: {len(checks)} finding(s)" + ("" if checks else
               " (no copies, repeated segments, time-reversed stretches or jumps found)"))
    for finding in checks:
        click.echo(f"  {finding['message']}")
    for f in doc["files"]:
        if not f["recorded_velocity"]:
            click.echo(f"  {f['path']} records no velocity (dq_servo or dq), so time reversal is not checked")
    sp = doc.get("splits")
    if sp:
        click.echo(f"splits ({sp['eval_set']} validation and test sets for {len(doc['joints'])} joints): "
                   f"about {sp['need_s']:.0f} s of recording needed for the full sizes, "
                   f"{sp['have_s']:.0f} s here")
