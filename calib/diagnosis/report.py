"""A self-contained HTML report of a diagnosis: tables and matplotlib figures embedded as PNG."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from calib.diagnosis.assemble import Diagnosis
from calib.stages.stage import AXES

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } .num { text-align: right; font-variant-numeric: tabular-nums; }
.ok { color: #1a7f37; } .bad { color: #b42318; } .note { color: #555; font-size: 0.9em; }
img { max-width: 100%; }
"""


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return '<img alt="figure" src="data:image/png;base64,' + base64.b64encode(buf.getvalue()).decode() + '">'


def _e(x) -> str:
    return html.escape(str(x))


def _num(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_num(x, digits) for x in v) + "]"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return _e(v)
    if not np.isfinite(f):
        return "-"
    return f"{f:.{digits}g}"


def write_report(diag: Diagnosis, directory: str | Path, title: str = "recording") -> Path:
    """Write ``index.html`` (figures embedded) into ``directory``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    d = diag.to_dict()
    parts = [(f"<!doctype html><html><head><meta charset='utf-8'><title>gyrocal diagnosis: {_e(title)}</title>"
             f"<style>{_CSS}</style></head><body>")]
    parts.append(f"<h1>Simulation against reality: {_e(title)}</h1>")
    info = d["info"]
    ch = ", ".join(k for k, v in info["channels"].items() if v) or "gyro only"
    parts.append(f"<p class='note'>{info['samples']} samples, {info['duration_s']:.1f} s at {info['sample_rate_hz']:.4g} Hz; "
                 f"channels: {_e(ch)}; {info['n_boot']} simulated replicates; {info.get('seconds', 0):.1f} s.</p>")
    parts.append(_verdict(d))
    parts.append(_effects_table(d))
    parts.append("<h2>The recording next to its simulation</h2>")
    parts.append("<p class='note'>Each residual feature of the recording, in standard deviations of the same feature over "
                 "recordings simulated from the fitted model: grey band = 95 % of the simulations. Left: the nominal model; "
                 "right: with the named effects switched on in the simulator.</p>")
    parts.append(_png(_feature_figure(diag)))
    parts.append(_png(_stills_figure(diag)))
    if diag.details["layout"].J:
        parts.append(_png(_closure_figure(diag)))
    tb = diag.details["tb"]
    if tb.lost or tb.host:
        parts.append(_png(_time_figure(diag)))
    if diag.details["plateaus"]:
        parts.append(_png(_saturation_figure(diag)))
    parts.append(_mismatch_table(d))
    parts.append(_unexplained(d))
    parts.append(_recalibration(d))
    parts.append(_tests_table(d))
    parts.append("</body></html>")
    path = out / "index.html"
    path.write_text("\n".join(parts))
    return path


def _verdict(d: dict) -> str:
    if d["effects"]:
        names = ", ".join(f"<b>{_e(e['name'])}</b>" for e in d["effects"])
        s = f"<p>Found: {names}.</p>"
    else:
        s = "<p class='ok'>The nominal model g = K m + b explains the recording: no catalogued effect is needed.</p>"
    if d["unexplained"]:
        s += f"<p class='bad'>{len(d['unexplained'])} mismatch(es) no catalogued effect explains: see below.</p>"
    if d["not_identifiable"]:
        s += "<p class='note'>Not identifiable with this recording: " + ", ".join(_e(n["name"]) for n in d["not_identifiable"]) + ".</p>"
    return s


def _effects_table(d: dict) -> str:
    if not d["effects"]:
        return ""
    rows = [("<h2>Effects</h2><table><tr><th>effect</th><th>what the data show</th><th>parameters</th>"
            "<th>fit before &rarr; after (lower is better)</th><th>reproduce</th></tr>")]
    for e in d["effects"]:
        params = "<br>".join(f"{_e(k)} = {_num(v)} &plusmn; {_num(e['uncertainty'].get(k))}" if k in e["uncertainty"]
                             else f"{_e(k)} = {_num(v)}" for k, v in e["parameters"].items())
        ev = e["evidence"]
        told = "".join(f"<br><span class='note'>Told apart from {_e(t['rival'])}: {_e(t['summary'])}.</span>"
                       for t in ev.get("rivals", []))
        rows.append(f"<tr><td>{_e(e['name'])}</td><td>{_e(ev.get('summary', ''))}{told}</td><td>{params}</td>"
                    f"<td class='num'>{_num(e['fit']['before'], 6)} &rarr; {_num(e['fit']['after'], 6)}</td>"
                    f"<td><code>gyrocal simulate --effect {_e(ev.get('simulate', ''))}</code></td></tr>")
    rows.append("</table>")
    return "".join(rows)


def _mismatch_table(d: dict) -> str:
    if not d["mismatches"]:
        return "<h2>Mismatches</h2><p class='ok'>No residual feature lies outside what the nominal simulation produces.</p>"
    rows = [("<h2>Mismatches (recording against the nominal simulation)</h2><table><tr><th>where</th><th>statistic</th>"
            "<th>observed</th><th>simulated 95 % range</th><th>p-value</th></tr>")]
    for m in d["mismatches"][:40]:
        rows.append(f"<tr><td>{_e(m['where'])}</td><td>{_e(m['statistic'])}</td><td class='num'>{_num(m['observed'])}</td>"
                    f"<td class='num'>{_num(m['simulated_range'])}</td><td class='num'>{_num(m['p_value'], 2)}</td></tr>")
    rows.append("</table>")
    return "".join(rows)


def _unexplained(d: dict) -> str:
    if not d["unexplained"]:
        return ""
    items = "".join(f"<li>{_e(u.get('description', ''))}</li>" for u in d["unexplained"])
    return f"<h2>Unexplained</h2><ul>{items}</ul>"


def _recalibration(d: dict) -> str:
    r = d.get("recalibration")
    if not r:
        return ""
    rows = [("<h2>Calibration with the effects modelled</h2><table><tr><th></th><th>nominal</th><th>with effects</th>"
            "<th>shift (standard errors)</th></tr>")]
    for key, label in (("k", "k"), ("b", "b (deg/s)")):
        for i, a in enumerate(AXES):
            rows.append(f"<tr><td>{label}<sub>{a}</sub></td><td class='num'>{r['nominal'][key][i]:.6g} &plusmn; "
                        f"{_num(r['nominal'][key + '_std'][i], 2)}</td><td class='num'>{r[key][i]:.6g} &plusmn; "
                        f"{_num(r[key + '_std'][i], 2)}</td><td class='num'>{r['shift_sigma'][key][i]:+.2f}</td></tr>")
    rows.append("</table>")
    rows += [f"<p class='note'>{_e(n)}</p>" for n in r["notes"]]
    return "".join(rows)


def _tests_table(d: dict) -> str:
    t = d["info"]["tests"]
    if not t:
        return ""
    rows = [("<h2>Tests</h2><table><tr><th>effect</th><th>statistic</th><th>p-value (null bootstrap)</th><th>threshold</th>"
            "</tr>")]
    for name, v in t.items():
        cls = "bad" if v["p_value"] < v["threshold"] else ""
        rows.append(f"<tr><td>{_e(name)}</td><td class='num'>{_num(v['statistic'])}</td><td class='num {cls}'>"
                    f"{_num(v['p_value'], 2)}</td><td class='num'>{_num(v['threshold'], 2)}</td></tr>")
    rows.append("</table>")
    if d["not_identifiable"]:
        rows.append("<ul>" + "".join(f"<li>{_e(n['name'])}: {_e(n['reason'])}</li>" for n in d["not_identifiable"]) + "</ul>")
    return "".join(rows)


# --------------------------------------------------------------------------- figures


def _z(obs: np.ndarray, boot: np.ndarray) -> np.ndarray:
    mu = np.nanmean(boot, axis=0)
    sd = np.nanstd(boot, axis=0, ddof=1)
    return (obs - mu) / np.where(sd > 0, sd, np.inf)


def _feature_figure(diag: Diagnosis):
    import matplotlib.pyplot as plt

    det = diag.details
    f = det["features"]
    obs = f.values[0]
    panels = [("nominal simulation", det["boot"])]
    if det["boot_after"] is not None:
        panels.append(("simulation with the named effects", det["boot_after"]))
    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 4.2), squeeze=False, sharey=True)
    colours = {"still_rate": "tab:blue", "whiteness": "tab:purple", "closure": "tab:orange", "tilt": "tab:green",
               "gravity": "tab:red"}
    x = np.arange(obs.size)
    for ax, (label, boot) in zip(axes[0], panels, strict=False):
        z = _z(obs, boot)
        ax.axhspan(-1.96, 1.96, color="0.9")
        for g, c in colours.items():
            sel = [i for i, gg in enumerate(f.groups) if gg == g]
            if sel:
                ax.plot(x[sel], np.clip(z[sel], -50, 50), "o", color=c, ms=4, label=g.replace("_", " "))
        ax.axhline(0, color="0.5", lw=0.8)
        ax.set_title(label)
        ax.set_xlabel("feature (stills in time order, then turns)")
        ax.set_ylabel("recording - simulations (std; clipped at 50)")
        ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig


def _stills_figure(diag: Diagnosis):
    import matplotlib.pyplot as plt

    det = diag.details
    f = det["features"]
    lay = det["layout"]
    obs = f.values[0]
    boot = det["boot"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    tmid = np.array([0.5 * (s.start_s + s.end_s) for s in lay.stills])
    for i, a in enumerate(AXES):
        sel = [f.names.index(f"still_rate_{s}_{a}") for s in range(lay.S)]
        sd = np.nanstd(boot[:, sel], axis=0, ddof=1)
        axes[i].errorbar(tmid, obs[sel], yerr=1.96 * sd, fmt="o", color="tab:blue", label="recording (95 % noise)")
        if det["boot_after"] is not None:
            mu = np.nanmean(det["boot_after"][:, sel], axis=0)
            axes[i].plot(tmid, mu, "s--", color="tab:red", mfc="none", label="simulation with the effects")
        axes[i].axhline(0, color="0.5", lw=0.8)
        axes[i].set_title(f"calibrated rate at rest, {a}")
        axes[i].set_xlabel("time (s)")
    axes[0].set_ylabel("deg/s")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def _closure_figure(diag: Diagnosis):
    import matplotlib.pyplot as plt

    det = diag.details
    f = det["features"]
    lay = det["layout"]
    obs = f.values[0]
    boot = det["boot"]
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * lay.J + 3), 3.6))
    w = 0.25
    for i, a in enumerate(AXES):
        sel = [f.names.index(f"closure_{j}_{a}") for j in range(lay.J)]
        sd = np.nanstd(boot[:, sel], axis=0, ddof=1)
        xs = np.arange(lay.J) + (i - 1) * w
        ax.bar(xs, obs[sel], w, yerr=1.96 * sd, label=f"{a} component", alpha=0.8)
    ax.axhline(0, color="0.4", lw=0.8)
    ax.set_xticks(np.arange(lay.J), [f"{s.axis} @ {s.start_s:.0f} s" for s in lay.turns], rotation=45, fontsize=8)
    ax.set_ylabel("closing rotation (deg)")
    ax.set_title("How far each turn ends from where it began (nominal fit; bars: 95 % of simulations)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _time_figure(diag: Diagnosis):
    import matplotlib.pyplot as plt

    det = diag.details
    tb = det["tb"]
    rec = det["raw"]  # the recording as delivered, with its gaps
    host = getattr(rec, "host_t", None)
    if host is None and det.get("host_t") is not None and len(det["host_t"]) == len(rec):
        host = det["host_t"]
    panels = 2 if (host is not None and tb.clock_e is not None) else 1
    fig, axes = plt.subplots(1, panels, figsize=(6.5 * panels, 3.4), squeeze=False)
    ax = axes[0, 0]
    t = rec.t - rec.t[0]
    rows = np.arange(t.size)
    ax.plot(t, (t - rows * tb.period) * 1e3, label="timestamps against consecutive rows")
    ax.plot(t, (t - (tb.index - tb.index[0]) * tb.period) * 1e3, label="timestamps against the sample numbers")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("ms")
    ax.set_title(f"Samples: {tb.lost} lost in {len(tb.gaps)} gaps")
    ax.legend(fontsize=8)
    if panels == 2:
        ax = axes[0, 1]
        h = np.asarray(host, dtype=float)
        n = (tb.index - tb.index[0]) * tb.period
        resid = (h - h[0]) - n
        ax.plot(n, resid * 1e3, ".", ms=2, label="host receive time - device time")
        ax.plot(n, (n / (1.0 + tb.clock_e) - n) * 1e3 + np.median(resid - (n / (1.0 + tb.clock_e) - n)) * 1e3,
                label=f"fitted clock error {tb.clock_e * 100:+.3f} %")
        ax.set_xlabel("device time (s)")
        ax.set_ylabel("ms")
        ax.set_title("Device clock against the host")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _saturation_figure(diag: Diagnosis):
    import matplotlib.pyplot as plt

    det = diag.details
    rec = det["rec"]
    fig, ax = plt.subplots(figsize=(8, 3.4))
    t = rec.t - rec.t[0]
    for i, a in enumerate(AXES):
        ax.plot(t, rec.gyro[:, i], lw=0.8, label=a)
    for p in det["plateaus"]:
        ax.axvspan(t[p.start], t[p.end - 1], color="red", alpha=0.2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("reading (deg/s)")
    ax.set_title("Readings at the gyro's full scale (red)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
