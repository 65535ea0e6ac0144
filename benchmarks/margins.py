"""Paired margins of one preset over the others, from ablation results merged across files.

    python -m benchmarks.margins ablation_noisy_600s ablation_noisy_600s_baselines [...]
                                 [--reference ebad] [--name margins_noisy_600s]

Each source is a ``benchmarks.ablation`` JSON (a name in benchmarks/results, or a path). Its
rows are merged; for every setting, each preset's mean ± std over seeds is printed with the
reference preset's margin over it, paired per seed (the reference minus the preset, seed by
seed, then the mean), for the novel views (refined test poses) and the deblurred training
frames, PSNR and SSIM. The stronger 3dgs of a setting (``3dgs`` or ``3dgs-po``, the higher mean
novel PSNR) is marked: the issue's margins are taken against it.

Rows are only paired when they were made with the same budget (scene size, seconds, step cap
and test-pose refinement): a source that differs is an error naming both files. A preset, setting
and seed found in two sources is an error too. The sources' dates and commands are printed, so
a reader sees when each row ran.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ._common import RESULTS, write_json
from .ablation import REFINE_ITERS

__all__ = ["load_rows", "paired_margins", "stronger_3dgs", "table", "plot", "main"]

KEYS = ("test_refined_psnr", "deblur_psnr", "test_refined_ssim", "deblur_ssim")
LABELS = {"ideal": "idealised, exact poses", "noisy": "realistic, noisy poses", "sfm": "realistic, SfM poses"}
BUDGET = ("size", "seconds", "iters", "refine_iters")  # what must agree for two rows to be paired


class MarginsError(ValueError):
    """A source that cannot be read or paired; the message names the file."""


def _resolve(source: str) -> Path:
    p = Path(source)
    if p.suffix == ".json" and p.exists():
        return p
    named = RESULTS / f"{source}.json"
    if named.exists():
        return named
    raise MarginsError(f"{source}: no such results file (looked for {p} and {named})")


def _refine_iters(argv: list[str]) -> int | None:
    """The ``--refine-iters`` of an ablation command line (its default when absent)."""
    for i, a in enumerate(argv):
        if a == "--refine-iters" and i + 1 < len(argv):
            return int(argv[i + 1])
        if a.startswith("--refine-iters="):
            return int(a.split("=", 1)[1])
    return REFINE_ITERS  # benchmarks.ablation's default


def load_rows(sources: list[str]) -> tuple[list[dict], list[dict]]:
    """The rows of every source, each tagged with its ``source`` and budget, and one header per
    source (name, date, command, budget). Raises MarginsError naming the file on a bad source, a
    budget that differs between sources, or a (setting, preset, seed) found twice."""
    rows: list[dict] = []
    headers: list[dict] = []
    seen: dict[tuple, str] = {}
    for source in sources:
        path = _resolve(source)
        try:
            d = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise MarginsError(f"{path}: cannot read it as JSON ({exc})") from exc
        if not isinstance(d, dict) or not isinstance(d.get("rows"), list) or not d["rows"]:
            raise MarginsError(f"{path}: no 'rows' of a benchmarks.ablation result")
        argv = [str(a) for a in d.get("argv", [])]
        budget = {
            "size": d.get("size"),
            "seconds": d.get("seconds"),
            "iters": d.get("iters"),
            "refine_iters": _refine_iters(argv),
        }
        if headers and any(budget[k] != headers[0]["budget"][k] for k in BUDGET):
            raise MarginsError(
                f"{path}: budget {budget} differs from {headers[0]['path']}'s "
                f"{headers[0]['budget']}; rows of different budgets are not paired"
            )
        headers.append(
            {
                "path": str(path),
                "name": path.stem,
                "date_utc": d.get("environment", {}).get("date_utc"),
                "commit": d.get("environment", {}).get("commit"),
                "argv": argv,
                "budget": budget,
            }
        )
        for r in d["rows"]:
            missing = [k for k in ("setting", "preset", "seed") if k not in r]
            if missing:
                raise MarginsError(f"{path}: a row without {missing}")
            key = (r["setting"], r["preset"], r["seed"])
            if key in seen:
                raise MarginsError(
                    f"{path}: {r['preset']} in setting {r['setting']}, seed {r['seed']}, is in {seen[key]} too"
                )
            seen[key] = str(path)
            rows.append({**r, "source": path.stem})
    return rows, headers


def _mean_std(values: list[float | None]) -> tuple[float, float] | None:
    a = np.asarray([v for v in values if v is not None], dtype=float)
    return None if a.size == 0 else (float(a.mean()), float(a.std()))


def stronger_3dgs(by_preset: dict[str, list[dict]]) -> str | None:
    """``3dgs`` or ``3dgs-po``, whichever has the higher mean novel PSNR (None when neither ran)."""
    cands = {
        p: _mean_std([r.get("test_refined_psnr") for r in rs])
        for p, rs in by_preset.items()
        if p in ("3dgs", "3dgs-po")
    }
    cands = {p: m for p, m in cands.items() if m is not None}
    return max(cands, key=lambda p: cands[p][0]) if cands else None


def paired_margins(rows: list[dict], reference: str = "ebad") -> dict:
    """For every setting and preset: its mean ± std of each key, steps and sources, and the
    reference's margin over it paired per seed (``per_seed``, ``mean``, ``seeds``; None where the
    two share no seed or a key is missing)."""
    out: dict = {}
    for setting in dict.fromkeys(r["setting"] for r in rows):
        by: dict[str, list[dict]] = {}
        for r in rows:
            if r["setting"] == setting:
                by.setdefault(r["preset"], []).append(r)
        ref = {r["seed"]: r for r in by.get(reference, [])}
        strong = stronger_3dgs(by)
        entry: dict = {}
        for preset, rs in by.items():
            e: dict = {
                "seeds": sorted(r["seed"] for r in rs),
                "sources": sorted({r["source"] for r in rs}),
                "steps": _mean_std([r.get("steps") for r in rs]),
                "stronger_3dgs": preset == strong,
            }
            for k in KEYS:
                e[k] = _mean_std([r.get(k) for r in rs])
            if preset != reference and ref:
                e["margin"] = {}
                for k in KEYS:
                    seeds = sorted(s for s in ref if any(r["seed"] == s for r in rs))
                    diffs = {}
                    for s in seeds:
                        other = next(r for r in rs if r["seed"] == s)
                        if ref[s].get(k) is not None and other.get(k) is not None:
                            diffs[s] = float(ref[s][k] - other[k])
                    e["margin"][k] = (
                        {"mean": float(np.mean(list(diffs.values()))), "per_seed": diffs, "seeds": sorted(diffs)}
                        if diffs
                        else None
                    )
            entry[preset] = e
        out[setting] = entry
    return out


def _fmt(ms: tuple[float, float] | None, digits: int) -> str:
    return "-" if ms is None else f"{ms[0]:.{digits}f} ± {ms[1]:.{digits}f}"


def _fmt_margin(m: dict | None, digits: int) -> str:
    if m is None:
        return "-"
    per = ", ".join(f"{v:+.{digits}f}" for v in m["per_seed"].values())
    return f"{m['mean']:+.{digits}f} ({per})"


def table(margins: dict, reference: str) -> str:
    lines = [
        f"| setting | preset | novel PSNR dB | deblurred PSNR dB | novel SSIM | deblurred SSIM | steps | "
        f"{reference} minus it, novel PSNR (by seed) | deblurred PSNR (by seed) | novel SSIM | deblurred SSIM | "
        f"source |",
        "|" + "---|" * 12,
    ]
    for setting, by in margins.items():
        for preset, e in by.items():
            m = e.get("margin") or {}
            name = f"`{preset}`" + (" (the stronger 3dgs)" if e["stronger_3dgs"] else "")
            steps = "-" if e["steps"] is None else f"{e['steps'][0]:.0f}"
            lines.append(
                f"| {setting} | {name} | {_fmt(e['test_refined_psnr'], 2)} | {_fmt(e['deblur_psnr'], 2)} | "
                f"{_fmt(e['test_refined_ssim'], 3)} | {_fmt(e['deblur_ssim'], 3)} | {steps} | "
                f"{_fmt_margin(m.get('test_refined_psnr'), 2)} | {_fmt_margin(m.get('deblur_psnr'), 2)} | "
                f"{_fmt_margin(m.get('test_refined_ssim'), 3)} | {_fmt_margin(m.get('deblur_ssim'), 3)} | "
                f"{', '.join(e['sources'])} |"
            )
    return "\n".join(lines)


def plot(margins: dict, reference: str, path, title: str = "") -> None:
    """One panel per setting: each preset's mean novel and deblurred PSNR with its std over seeds,
    the reference preset's bars outlined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settings = list(margins)
    fig, axes = plt.subplots(1, len(settings), figsize=(4.2 * len(settings), 3.8), squeeze=False, sharey=True)
    for ax, setting in zip(axes[0], settings):
        presets = list(margins[setting])
        x = np.arange(len(presets))
        for off, key, label in (
            (-0.2, "test_refined_psnr", "novel views (refined poses)"),
            (0.2, "deblur_psnr", "deblurred training frames"),
        ):
            vals = [margins[setting][p][key] for p in presets]
            ax.bar(
                x + off,
                [v[0] if v else np.nan for v in vals],
                0.4,
                yerr=[v[1] if v else 0 for v in vals],
                capsize=3,
                label=label,
                edgecolor=["black" if p == reference else "none" for p in presets],
                linewidth=1.2,
            )
        ax.set_xticks(x, presets, rotation=30, ha="right")
        ax.set_title(LABELS.get(setting, setting))
        ax.grid(axis="y", alpha=0.3)
        lo = min(
            v[0]
            for p in presets
            for v in (margins[setting][p]["test_refined_psnr"], margins[setting][p]["deblur_psnr"])
            if v
        )
        ax.set_ylim(max(0.0, lo - 3.0), None)
    axes[0, 0].set_ylabel("PSNR dB, mean ± std over seeds")
    axes[0, 0].legend(loc="lower left", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sources", nargs="+", help="benchmarks.ablation results: names in benchmarks/results or paths")
    ap.add_argument("--reference", default="ebad", help="the preset whose margins are taken (default ebad)")
    ap.add_argument("--name", default=None, help="also write benchmarks/results/NAME.json and NAME.png (a bar chart)")
    args = ap.parse_args(argv)
    try:
        rows, headers = load_rows(args.sources)
    except MarginsError as exc:
        print(f"benchmarks.margins: {exc}", file=sys.stderr)
        return 2
    margins = paired_margins(rows, args.reference)
    if not any(args.reference in by for by in margins.values()):
        print(
            f"benchmarks.margins: no row of the reference preset {args.reference!r} in {args.sources}", file=sys.stderr
        )
        return 2
    b = headers[0]["budget"]
    print(
        f"{b['size']}, {b['seconds']:g} s and at most {b['iters']} steps per run, test poses refined "
        f"({b['refine_iters']} steps at most); mean ± std over seeds, margins paired per seed"
    )
    for h in headers:
        commit = f", commit {h['commit']}" if h.get("commit") else ""
        print(f"  {h['name']}: {h['date_utc']}{commit}: {' '.join(h['argv'])}")
    print()
    print(table(margins, args.reference))
    if args.name:
        path = write_json(
            args.name, {"reference": args.reference, "sources": headers, "margins": margins, "argv": sys.argv[1:]}
        )
        b = headers[0]["budget"]
        plot(
            margins,
            args.reference,
            path.with_suffix(".png"),
            f"{b['size']} scene, {b['seconds']:g} s per run, seeds pooled as mean ± std",
        )
        print(f"\nwrote {path} and {path.with_suffix('.png').name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
