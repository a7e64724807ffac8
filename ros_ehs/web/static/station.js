// ros_ehs station page: frames over a WebSocket, buttons through /api/action (docs/station.md).
'use strict';
(function () {
  const $ = (id) => document.getElementById(id);
  const params = new URLSearchParams(location.search);
  const token = params.get('token') || '';
  // what the tests and the station benchmark read: frames received, the newest frame, and the
  // page's own log (the link, the buttons' state and why, presses, the dialog), newest last
  // (its last LOG_LINES lines; ``noted`` counts every line)
  const state = window.station = { frames: 0, last: null, paused: false, connected: false,
                                   log: [], noted: 0 };
  const LOG_LINES = 200;
  function note(what) {
    state.log.push(`${(performance.now() / 1000).toFixed(3)} s: ${what}`);
    state.noted += 1;
    if (state.log.length > LOG_LINES) state.log.shift();
  }
  const SCALE = { position: 1e3, reference: 1e3, error: 1e6, force: 1e-3, current: 1e3 };
  const UNIT = { position: 'mm', reference: 'mm', error: 'um', force: 'kN', current: 'mA' };
  const COLOR = { position: '#1565c0', reference: '#2e7d32', error: '#c62828',
                  force: '#6a1b9a', current: '#ef6c00' };

  const esc = (t) => String(t).replace(/[&<>"]/g,
    (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;' })[c]);
  // write an element's HTML only when it changed: a frame that changes nothing costs no layout
  function put(id, html) {
    const el = $(id);
    if (el.dataset.html !== html) { el.innerHTML = html; el.dataset.html = html; }
  }
  function fmt(x, digits) {
    if (x === null || x === undefined || Number.isNaN(x)) return '-';
    return Number(x).toPrecision(digits || 4);
  }

  function chart(el, channels, height) {
    const series = [{}];
    const bands = [];
    const axes = [{ label: 's' }];
    const scales = {};
    channels.forEach((c, k) => {
      const hi = series.length;
      // no points: 400 slots are a line (uPlot draws a marker at each point of a sparse series)
      series.push({ label: `${c} max [${UNIT[c]}]`, stroke: COLOR[c], scale: UNIT[c],
                    spanGaps: false, points: { show: false } });
      series.push({ label: `${c} min`, stroke: COLOR[c], scale: UNIT[c], spanGaps: false,
                    points: { show: false } });
      bands.push({ series: [hi, hi + 1], fill: COLOR[c] + '33' });
      if (!scales[UNIT[c]]) {
        scales[UNIT[c]] = {};
        axes.push({ scale: UNIT[c], label: UNIT[c], side: Object.keys(scales).length > 1 ? 1 : 3,
                    grid: { show: Object.keys(scales).length === 1 } });
      }
    });
    const width = Math.max(500, el.parentElement.clientWidth - 30);
    const opts = { width, height, series, bands, axes, scales: { x: { time: false }, ...scales },
                   legend: { live: false } };
    const data = [[]].concat(channels.flatMap(() => [[], []]));
    return { plot: new uPlot(opts, data, el), channels };
  }

  const charts = [chart($('chart-z'), ['position', 'reference', 'error'], 300),
                  chart($('chart-f'), ['force', 'current'], 220)];
  let trend = null;

  // the scope comes as one base64 block of float32 rows (t, then each channel's min and max)
  function unpack(scope) {
    const bytes = Uint8Array.from(atob(scope.data), (ch) => ch.charCodeAt(0));
    const all = new Float32Array(bytes.buffer);
    const rows = {};
    scope.rows.forEach((name, k) => { rows[name] = all.subarray(k * scope.n, (k + 1) * scope.n); });
    return rows;
  }

  function drawScope(scope) {
    const rows = unpack(scope);
    const scaled = (a, s) => Array.from(a, (v) => (Number.isNaN(v) ? null : v * s));
    for (const c of charts) {
      const data = [Array.from(rows.t)];
      for (const ch of c.channels) {
        data.push(scaled(rows[`${ch}.max`], SCALE[ch]));
        data.push(scaled(rows[`${ch}.min`], SCALE[ch]));
      }
      c.plot.setData(data);
    }
  }

  function drawMeters(f) {
    const rows = Object.entries(f.meters).map(([name, m]) => {
      const s = SCALE[name];
      const cells = ['value', 'peak', 'valley', 'min', 'max']
        .map((k) => `<td data-meter="${name}.${k}">${m[k] === null ? '-' : fmt(m[k] * s)}</td>`);
      const label = name === 'force' ? `force (${f.force_source})` : name;
      return `<tr><td>${label} [${UNIT[name]}]</td>${cells.join('')}</tr>`;
    });
    put('meters', rows.join(''));
  }

  function drawSafety(f) {
    const ctl = f.controller ? f.controller.values : {};
    const enabled = ctl.enabled === 'True';
    $('hyd').textContent = f.controller ? (enabled ? 'on' : 'off') : '-';
    $('ramp').value = Number(ctl.ramp || 0);
    $('mode').textContent = ctl.control_mode ? `${ctl.control_mode} (${ctl.mode})` : '-';
    $('interlock').textContent = ctl.interlock || '-';
    put('detectors', f.detectors.map((d) => {
      const cls = d.latched ? 'latched' : '';
      const lim = d.limit === null ? '-' : `${fmt(d.limit)} ${d.unit}`;
      return `<tr class="${cls}" data-detector="${d.name}"><td>${d.name}</td><td>${lim}</td>` +
             `<td>${d.action}</td><td>${d.latched ? 'TRIPPED' : 'clear'}</td>` +
             `<td>${d.trips}</td></tr>`;
    }).join(''));
  }

  function drawProcedure(f) {
    const p = f.procedure;
    if (!p) { put('proc', 'no procedure node heard'); return; }
    const v = p.values;
    const ttg = Number(v.time_to_go_s);
    put('proc', `<div>state <b data-testid="proc-state">${esc(v.state || p.message)}</b>` +
      ` &middot; step ${esc(v.step_index || '-')} <b>${esc(v.step || '')}</b></div>` +
      `<div>cycles: step <b data-testid="step-cycles">${v.step_cycles || 0}</b>, total ` +
      `<b data-testid="total-cycles">${v.total_cycles || 0}</b> &middot; time to go ` +
      `${Number.isFinite(ttg) ? ttg.toFixed(0) + ' s' : '-'}</div>` +
      (v.reason ? `<div class="note">${esc(v.reason)}</div>` : ''));
  }

  function drawEstimate(f) {
    const e = f.estimate;
    if (!e) return;
    const rows = Object.entries(e.params).map(([k, p]) =>
      `<tr><td>${k}</td><td>${fmt(p.value)}</td><td>&plusmn; ${fmt(p.stderr, 2)}</td></tr>`);
    const failed = (e.failed || []).map((r) => `<span class="tag">${esc(r)}</span>`).join(' ');
    put('estimate', `<div>${e.adequate ? 'adequate' : 'NOT ADEQUATE'}` +
      `${e.pushed ? ', pushed to the controller' : ''}: <span class="note">${esc(e.message)}</span>` +
      `</div>` + (failed ? `<div data-testid="failed-rules">failed: ${failed}</div>` : '') +
      `<table>${rows.join('')}</table>`);
    const names = Object.keys(f.trend);
    if (!names.length) return;
    if (!trend || trend.names.join() !== names.join()) {
      $('chart-trend').innerHTML = '';
      const series = [{}].concat(names.map((n, k) => ({ label: n,
        stroke: `hsl(${(k * 67) % 360} 60% 40%)` })));
      trend = { names, plot: new uPlot({ width: 360, height: 160, series,
        scales: { x: { time: false } }, axes: [{ label: 's' }, { label: 'x / newest' }] },
        [[]].concat(names.map(() => [])), $('chart-trend')) };
    }
    // every parameter's estimates relative to its newest, on one time axis
    const t = f.trend[names[0]].map((p) => p[0]);
    trend.plot.setData([t].concat(names.map((n) => {
      const pts = f.trend[n];
      const last = pts[pts.length - 1][1];
      return pts.map((p) => p[1] / last);
    })));
  }

  // the campaign's S-N plot as SVG: lives (cycles) across, levels up, both logarithmic;
  // failures filled, run-outs open with an arrow (their lives are longer than shown), the
  // median curve and its 10 % .. 90 % band. Drawn here, not with uPlot: uPlot's line charts
  // need one life per point across (run-outs share theirs)
  const SN = { w: 560, h: 300, l: 64, r: 12, t: 10, b: 36 };
  function snSvg(c) {
    const pts = c.points;
    const cv = c.curves;
    const xs = pts.failed[0].concat(pts.run_out[0], cv ? cv.p10.concat(cv.p90) : []);
    const ys = pts.failed[1].concat(pts.run_out[1], cv ? cv.load : []);
    if (!xs.length) return '<p class="note">no specimen ended yet</p>';
    const lx = xs.map(Math.log10);
    const ly = ys.map(Math.log10);
    const x0 = Math.floor(Math.min(...lx));
    const x1 = Math.max(Math.ceil(Math.max(...lx) + 0.3), x0 + 1);
    let y0 = Math.min(...ly);
    let y1 = Math.max(...ly);
    const pad = Math.max(0.02, (y1 - y0) * 0.08);
    y0 -= pad; y1 += pad;
    const W = SN.w - SN.l - SN.r;
    const H = SN.h - SN.t - SN.b;
    const X = (n) => SN.l + (Math.log10(n) - x0) / (x1 - x0) * W;
    const Y = (s) => SN.t + (1 - (Math.log10(s) - y0) / (y1 - y0)) * H;
    const out = [`<svg class="sn" width="${SN.w}" height="${SN.h}" ` +
                 `viewBox="0 0 ${SN.w} ${SN.h}" role="img" aria-label="S-N plot">`];
    for (let d = x0; d <= x1; d += 1) {
      const x = X(10 ** d).toFixed(1);
      out.push(`<line class="grid" x1="${x}" x2="${x}" y1="${SN.t}" y2="${SN.t + H}"/>` +
               `<text x="${x}" y="${SN.t + H + 14}" text-anchor="middle">1e${d}</text>`);
    }
    for (let j = 0; j <= 4; j += 1) {
      const v = 10 ** (y0 + (y1 - y0) * j / 4);
      const y = Y(v).toFixed(1);
      out.push(`<line class="grid" x1="${SN.l}" x2="${SN.l + W}" y1="${y}" y2="${y}"/>` +
               `<text x="${SN.l - 4}" y="${y}" text-anchor="end" dy="4">` +
               `${Number(v.toPrecision(3))}</text>`);
    }
    out.push(`<rect class="frame" x="${SN.l}" y="${SN.t}" width="${W}" height="${H}"/>`,
             `<text x="${SN.l + W / 2}" y="${SN.h - 4}" text-anchor="middle">cycles</text>`,
             `<text transform="translate(12 ${SN.t + H / 2}) rotate(-90)" ` +
             `text-anchor="middle">level [${esc(c.unit || '-')}]</text>`);
    if (cv) {
      const line = (ns) => ns.map((n, k) => `${X(n).toFixed(1)},${Y(cv.load[k]).toFixed(1)}`);
      out.push(`<polygon class="band" data-testid="sn-band" points="` +
               `${line(cv.p10).concat(line(cv.p90).reverse()).join(' ')}"/>`);
      for (const p of ['p10', 'p50', 'p90']) {
        out.push(`<polyline class="${p}" data-testid="sn-${p}" points="${line(cv[p]).join(' ')}"/>`);
      }
    }
    pts.failed[0].forEach((n, k) => {
      out.push(`<circle class="failed" data-result="failed" cx="${X(n).toFixed(1)}" ` +
               `cy="${Y(pts.failed[1][k]).toFixed(1)}" r="4"/>`);
    });
    pts.run_out[0].forEach((n, k) => {
      const x = X(n);
      const y = Y(pts.run_out[1][k]);
      out.push(`<path class="arrow" d="M${(x + 5).toFixed(1)},${y.toFixed(1)} h14 ` +
               `m-5,-4 l5,4 l-5,4"/><circle class="run_out" data-result="run_out" ` +
               `cx="${x.toFixed(1)}" cy="${y.toFixed(1)}" r="4"/>`);
    });
    out.push('</svg>');
    return out.join('');
  }

  function drawCampaign(f) {
    const c = f.campaign;
    $('campaign').hidden = !c;
    if (!c) return;
    const u = c.unit ? ` ${esc(c.unit)}` : '';
    const n = c.counts;
    $('campaign-name').textContent = c.name || '';
    put('campaign-state', `<div>state <b data-testid="campaign-phase">${esc(c.state || '-')}` +
      `</b> &middot; ${esc(c.message)}` + (c.lost ? ` <span class="tag" data-testid=` +
      `"campaign-lost">${esc(c.lost)}</span>` : '') +
      `</div><div>${n.failed} failed, ${n.run_out} run out, ` +
      `${n.invalid} invalid` + (c.state === 'under_way' ? ` &middot; under way: ` +
      `<b>${esc(c.specimen)}</b> at ${fmt(c.under_way_level)}${u}` : '') +
      (c.next_level !== null ? ` &middot; next level <b data-testid="next-level">` +
       `${fmt(c.next_level)}</b>${u}` : '') +
      (c.fit ? ` &middot; fit: k ${fmt(c.fit.k, 3)}, scatter ${fmt(c.fit.s, 2)} decades` : '') +
      (c.verdict ? `</div><div><b>ended</b>: ${esc(c.verdict)}` : '') + '</div>');
    put('chart-sn', snSvg(c));
    put('specimens', c.specimens.map((r) =>
      `<tr class="${esc(r.result)}" data-specimen="${esc(r.specimen)}"><td>${esc(r.specimen)}` +
      `</td><td>${fmt(r.level)}</td><td>${esc(r.result)}</td>` +
      `<td>${r.cycles === null ? '-' : Math.round(r.cycles)}</td>` +
      `<td>${fmt(r.mean)}</td><td>${fmt(r.amplitude)}</td><td>${fmt(r.r_ratio, 3)}</td>` +
      `<td class="note">${esc(r.reason)}</td></tr>`).join(''));
  }

  // an event's own stamp: wall time in real time; in lock-step the loop's simulated seconds
  // (a stamp before 1973), with the time the station heard it
  function when(e) {
    const heard = new Date(e.at * 1000).toLocaleTimeString();
    if (e.stamp_ns === undefined || e.stamp_ns === null) return heard;
    if (e.stamp_ns > 1e17) return new Date(e.stamp_ns / 1e6).toLocaleTimeString();
    return `${heard} (loop ${(e.stamp_ns / 1e9).toFixed(3)} s)`;
  }

  function drawEvents(f) {
    $('events-total').textContent = `${f.events_total} in all`;
    put('events', f.events.slice().reverse().slice(0, 100).map((e) =>
      `<li class="l${e.level}">${when(e)} ` +
      `<b>${esc(e.source)} ${esc(e.kind)}</b> ${esc(e.message)}</li>`).join(''));
  }

  // why the buttons are off now ('' when on), as last logged
  const buttons = { why: null, noProcedure: null, noNext: null };
  function drawHeader(f) {
    const link = $('link');
    if (f.lost) { link.textContent = f.lost; link.className = 'badge error'; }
    else { link.textContent = 'connected'; link.className = 'badge ok'; }
    const c = f.controller;
    const axis = $('axis');
    axis.textContent = c ? c.message : 'no controller';
    axis.className = 'badge ' + (c ? ['ok', 'warn', 'error', 'error'][c.level] : 'warn');
    const may = f.may_act;
    $('rights').textContent = may.allowed ? 'operator' : 'read-only';
    $('rights').title = may.why;
    setButtons(!may.allowed ? may.why : (f.lost || ''), !f.procedure,
               !(f.campaign && f.campaign.state === 'ready' && !f.campaign.lost));
  }

  // every button that acts (the axis's, the procedure's, the campaign's, the meters' reset):
  // off while ``why`` says why; the procedure's also while no procedure runs, the next
  // specimen's while the campaign is not ready for one
  const PROCEDURE_ACTIONS = ['start', 'hold', 'resume', 'stop'];
  function setButtons(why, noProcedure, noNext) {
    if (why !== buttons.why || noProcedure !== buttons.noProcedure ||
        noNext !== buttons.noNext) {
      note(why ? `buttons off: ${why}` : `buttons on${noProcedure ? ' (no procedure)' : ''}` +
                 `${noNext ? '' : ' (next specimen)'}`);
      Object.assign(buttons, { why, noProcedure, noNext });
    }
    document.querySelectorAll('button.act, #meters-reset').forEach((b) => {
      b.disabled = Boolean(why) || (PROCEDURE_ACTIONS.includes(b.dataset.action) && noProcedure) ||
                   (b.dataset.action === 'next' && noNext);
    });
  }

  // the scope redraws every frame; the numbers at most TEXT_HZ times a second (a meter read by
  // eye needs no more, and each table rewrite costs the browser a layout)
  const TEXT_HZ = 5;
  let lastText = 0;
  function onFrame(frame) {
    state.frames += 1;
    if (frame.board) state.board = frame.board;      // the board comes a few times a second
    const f = Object.assign({}, state.board, frame);
    state.last = f;
    if (!state.paused) drawScope(f.scope);
    const now = performance.now();
    if (now - lastText < 1000 / TEXT_HZ) return;
    lastText = now;
    drawHeader(f);
    drawMeters(f);
    drawSafety(f);
    drawProcedure(f);
    drawEstimate(f);
    drawCampaign(f);
    drawEvents(f);
  }

  let ws = null;
  function connect() {
    const url = `ws://${location.host}/ws?span=${$('span').value}` +
                (token ? `&token=${encodeURIComponent(token)}` : '');
    const sock = ws = new WebSocket(url);
    ws.onopen = () => { state.connected = true; note('link open'); };
    let drawn = 0;                    // this connection's frames: the server sends on when drawn
    ws.onmessage = (m) => {
      onFrame(JSON.parse(m.data));
      drawn += 1;
      sock.send(JSON.stringify({ drawn }));
    };
    ws.onclose = (e) => {
      state.connected = false;
      note(`link closed (${e.code})`);
      setButtons('the link to the station is closed', buttons.noProcedure, buttons.noNext);
      $('link').textContent = 'station disconnected: retrying';
      $('link').className = 'badge error';
      setTimeout(connect, 1000);
    };
  }

  function answer(ok, text) {
    const a = $('answer');
    a.hidden = false;
    a.textContent = text;
    a.className = 'answer' + (ok ? '' : ' refused');
  }

  async function post(path, body) {
    const r = await fetch(path, { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                  body: JSON.stringify({ token, ...body }) });
    return r.json();
  }

  // ask in the page's own dialog; resolve true on Confirm, false on Cancel or Escape
  function confirmed(text) {
    const d = $('confirm');
    $('confirm-text').textContent = text;
    d.returnValue = '';
    return new Promise((resolve) => {
      d.addEventListener('close', () => {
        note(`dialog closed: ${d.returnValue || 'cancel'}`);
        resolve(d.returnValue === 'ok');
      }, { once: true });
      d.showModal();
      note('dialog open');
    });
  }

  const ASK = {
    enable: 'Turn the hydraulics ON? The axis ramps on from where it is.',
    disable: 'Turn the hydraulics OFF? The valve gets 0 A.',
    stop: 'Stop the test (to its safe point)?',
  };
  // a press is logged where it lands, also on a disabled button, which gets no click: then the
  // page says that nothing was sent, and why
  window.addEventListener('pointerdown', (e) => {
    const b = e.target.closest && e.target.closest('button');
    note(`press on ${b ? (b.dataset.testid || b.id) + (b.disabled ? ' (disabled)' : '')
                       : e.target.tagName.toLowerCase()}`);
    if (b && b.disabled && (b.classList.contains('act') || b.id === 'meters-reset')) {
      answer(false, `${b.dataset.action || 'meters'}: not sent: ` + (buttons.why ||
        (b.dataset.action === 'next' ? 'the campaign node is not ready for a specimen (or not heard)'
                                     : 'no procedure node heard')));
    }
  }, true);
  document.querySelectorAll('button.act').forEach((b) => b.addEventListener('click', async () => {
    const action = b.dataset.action;
    note(`click ${action}`);
    const body = {};
    if (ASK[action] && !(await confirmed(ASK[action]))) return;
    if (action === 'enable' || action === 'disable') body.confirm = true;
    if (action === 'next') body.specimen = $('specimen-id').value.trim();
    try {
      const r = await post(`/api/action/${action}`, body);
      answer(r.ok, `${action}: ${r.ok ? 'done' : 'refused'}: ${r.message}`);
      if (action === 'next' && r.ok) $('specimen-id').value = '';
      note(`${action}: ${r.ok ? 'done' : 'refused'}`);
    } catch (err) {
      answer(false, `${action}: no answer from the station (${err})`);
    }
  }));
  $('meters-reset').addEventListener('click', async () => {
    const r = await post('/api/meters/reset', {});
    if (!r.ok) answer(false, `meters: ${r.message}`);
  });
  $('pause').addEventListener('click', () => {
    state.paused = !state.paused;
    $('pause').textContent = state.paused ? 'Run' : 'Pause';
    $('scope-note').textContent = state.paused ? 'paused' : '';
  });
  $('span').addEventListener('change', () => {
    if (ws && ws.readyState === 1) ws.send(JSON.stringify({ span: Number($('span').value) }));
  });
  connect();
})();
