# Copyright 2026 ros_ehs contributors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
A campaign's report from its store: the S-N plot, the specimens, the fit, one HTML page.

* ``specimens.csv``: every record as stored (invalid ones with their reason);
* ``specimens_pylife.csv``: the valid ones in pyLife's layout (``load, cycles, fracture``);
* ``fit.json``: the maximum-likelihood Basquin fit (run-outs censored) with its slope
  interval, the 10/50/90 % curves' parameters and the median life's profile-likelihood
  interval at each tested level; ASTM E739's least squares (failures only) beside it, with
  its linearity F-test where levels are replicated;
* ``sn.png``: log-log, failures as dots, run-outs as arrows to the right, the 10/50/90 %
  curves, the median curve's confidence band (profile likelihood, at the fit's confidence);
* ``report.html``: one self-contained page (the plot inline) a lab can send.
"""

from __future__ import annotations

import base64
import csv
from dataclasses import asdict, dataclass
import html
import json
import math
import os
from pathlib import Path

import numpy as np
from ros_ehs.core.campaign.runner import sn_data
from ros_ehs.core.campaign.sn import fit_basquin, fit_e739, SNData
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.data.store import ResultStore

__all__ = ['CampaignReport', 'write_campaign_report']

#: the loads the plotted band is computed at (log-spaced over the tested ones)
BAND_POINTS = 12


@dataclass
class CampaignReport:
    """What :func:`write_campaign_report` found and wrote."""

    campaign: str
    specimens: int
    failed: int
    run_out: int
    invalid: int
    fit: dict | None             #: fit.json's content ('' reasons when there is none)
    files: list


def _pick(store: ResultStore, name: str) -> tuple[str, int]:
    names = store.names()
    if name:
        if name not in names:
            raise DataError(f'no campaign {name!r} in the store (it has: '
                            f'{sorted(names) or "none"})')
        return name, names[name]
    if len(names) != 1:
        raise InputError(f'the store holds {len(names)} campaigns ({sorted(names)}): name one '
                         'with --campaign')
    (only, cid), = names.items()
    return only, cid


def _fit_doc(data: SNData | None, confidence: float) -> tuple[dict, object | None]:
    if data is None or np.count_nonzero(data.failed) < 3:
        return {'basquin': None, 'why': 'three failures at two levels at least are needed'}, \
            None
    try:
        fit = fit_basquin(data, confidence)
    except InputError as err:
        return {'basquin': None, 'why': str(err)}, None
    levels = sorted({float(v) for v in data.load})
    doc = {'basquin': {
        'method': fit.method, 'a': fit.a, 'k': fit.k, 'scatter_decades': fit.s,
        'scatter_tn': fit.scatter_tn, 'loglik': fit.loglik, 'failures': fit.failures,
        'run_outs': fit.run_outs, 'confidence': confidence,
        'k_interval': list(fit.k_interval),
        'median_life': {f'{v:g}': {'life': float(fit.life(v)),
                                   'interval': list(fit.life_interval(v))} for v in levels},
        'curves': {f'{int(p * 100)}%': {
            'life_at': {f'{v:g}': float(fit.life(v, p)) for v in levels}}
            for p in (0.1, 0.5, 0.9)}}}
    try:
        e = fit_e739(data)
        doc['e739'] = {'method': e.method, 'a': e.a, 'k': e.k, 's': e.s, 'n': e.n,
                       'linearity_f': e.linearity_f, 'linearity_p': e.linearity_p}
    except InputError as err:
        doc['e739'] = {'why': str(err)}
    return doc, fit


def write_campaign_report(store: ResultStore, out: str | os.PathLike, campaign: str = '',
                          confidence: float = 0.9) -> CampaignReport:
    """Write a campaign's report (module docstring) into ``out``; return what it found."""
    name, cid = _pick(store, campaign)
    recs = store.results(cid)
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    path = d / 'specimens.csv'
    rows = [asdict(r) for r in recs]
    with open(path, 'w', newline='') as fh:
        cols = list(rows[0]) if rows else ['specimen']
        w = csv.DictWriter(fh, cols)
        w.writeheader()
        for r in rows:
            w.writerow({**r, 'bags': ';'.join(r['bags']), 'params': json.dumps(r['params'])})
    files.append(path)
    data = sn_data(recs)                    # the valid ones, as the campaign's rules fit them
    path = d / 'specimens_pylife.csv'
    with open(path, 'w', newline='') as fh:
        fh.write('load,cycles,fracture\n')
        if data is not None:
            for s, n, f in zip(data.load, data.cycles, data.failed):
                fh.write(f'{s:.10g},{int(n)},{bool(f)}\n')
    files.append(path)
    doc, fit = _fit_doc(data, confidence)
    doc['campaign'] = name
    path = d / 'fit.json'
    path.write_text(json.dumps(doc, indent=2, default=float) + '\n')
    files.append(path)
    png = _plot(d / 'sn.png', name, recs, fit, confidence)
    files.append(png)
    files.append(_html(d / 'report.html', name, recs, doc, png))
    counts = {k: sum(r.result == k for r in recs) for k in ('failed', 'run_out', 'invalid')}
    return CampaignReport(name, len(recs), counts['failed'], counts['run_out'],
                          counts['invalid'], doc, files)


def _plot(path: Path, name: str, recs, fit, confidence: float) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 5.5))
    f = [r for r in recs if r.result == 'failed' and r.cycles > 0]
    ro = [r for r in recs if r.result == 'run_out' and r.cycles > 0]
    if f:
        ax.plot([r.cycles for r in f], [r.level for r in f], 'o', color='C0', label='failed')
    for j, r in enumerate(ro):
        ax.annotate('', xy=(r.cycles * 2.0, r.level), xytext=(r.cycles, r.level),
                    arrowprops={'arrowstyle': '->', 'color': 'C1'})
        ax.plot([r.cycles], [r.level], '>', color='C1', label='run-out' if j == 0 else None)
    if fit is not None:
        loads = np.geomspace(min(r.level for r in f + ro) * 0.95,
                             max(r.level for r in f + ro) * 1.05, 60)
        for p, style in ((0.1, ':'), (0.5, '-'), (0.9, ':')):
            ax.plot(fit.life(loads, p), loads, style, color='k', lw=1.0,
                    label=f'{int(p * 100)} % failed')
        band = np.geomspace(loads[0], loads[-1], BAND_POINTS)
        lo, hi = np.array([fit.life_interval(float(v)) for v in band]).T
        ax.fill_betweenx(band, lo, hi, color='0.6', alpha=0.3,
                         label=f'median, {confidence * 100:g} % confidence')
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.set_xlabel('cycles')
    ax.set_ylabel('level (load or amplitude, as the campaign gives it)')
    ax.set_title(name)
    ax.grid(alpha=0.3, which='both')
    if f or ro:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _num(v) -> str:
    if isinstance(v, float):
        return '' if math.isnan(v) else f'{v:.6g}'
    return html.escape(str(v))


def _html(path: Path, name: str, recs, doc: dict, png: Path) -> Path:
    img = base64.b64encode(png.read_bytes()).decode()
    cols = ('specimen', 'level', 'result', 'cycles', 'peak', 'valley', 'r_ratio',
            'amplitude_spread', 'duration_s', 'reason')
    rows = ''.join('<tr>' + ''.join(f'<td>{_num(getattr(r, c))}</td>' for c in cols)
                   + '</tr>\n' for r in recs)
    b = doc.get('basquin')
    if b:
        fit = (f"<p>{html.escape(b['method'])}: log10 N = {b['a']:.4g} - {b['k']:.4g} "
               f"log10 S, scatter {b['scatter_decades']:.3g} decades (T<sub>N</sub> "
               f"{b['scatter_tn']:.3g}); slope {b['k']:.4g}, its {b['confidence'] * 100:g} % "
               f"interval {b['k_interval'][0]:.4g} .. {b['k_interval'][1]:.4g}; "
               f"{b['failures']} failures, {b['run_outs']} run-outs.</p>")
    else:
        fit = f"<p>No fit: {html.escape(doc.get('why', ''))}.</p>"
    e = doc.get('e739') or {}
    if 'k' in e:
        fit += (f"<p>{html.escape(e['method'])}: slope {e['k']:.4g}, s {e['s']:.3g} "
                f"decades, n = {e['n']}"
                + (f"; linearity F = {e['linearity_f']:.3g} (p = {e['linearity_p']:.3g})"
                   if e.get('linearity_f') is not None else '') + '.</p>')
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(name)}: S-N report</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #bbb;padding:2px 6px;
font-size:90%}}</style></head>
<body><h1>{html.escape(name)}</h1>
<h2>S-N curve</h2><img id="sn" alt="S-N plot" src="data:image/png;base64,{img}">
<h2>Fit</h2>{fit}
<h2>Specimens</h2>
<table id="specimens"><thead><tr>{''.join(f'<th>{c}</th>' for c in cols)}</tr></thead>
<tbody>
{rows}</tbody></table>
<p>Made by ros_ehs from its results store; run-outs are right-censored lives in the fit.</p>
</body></html>
"""
    path.write_text(page)
    return path
