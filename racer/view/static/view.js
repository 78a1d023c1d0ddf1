// racer view: the page's script. It polls the server's JSON endpoints (racer/view/app.py) and draws with plain
// canvas and inline SVG; nothing is loaded from elsewhere.
"use strict";

const LIVE_MS = 200;      // poses: a few updates a second
const STORE_MS = 3000;    // metrics, checkpoints, evaluations
const COLOURS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"];
const CHARTS = [
  // [key, title, source, x, y(row)]: metrics rows are per iteration; evaluations per checkpoint version.
  ["mean_reward", "mean reward", "metrics"],
  ["mean_progress", "mean progress %", "metrics"],
  ["completion", "robust evaluation: laps completed %", "evaluations"],
  ["best_lap_s", "evaluation: best lap s", "evaluations"],
  ["entropy", "entropy", "metrics"],
  ["approx_kl", "KL (approx.)", "metrics"],
  ["policy_loss", "policy loss", "metrics"],
  ["value_loss", "value loss", "metrics"],
  ["steps_per_s", "env steps/s", "metrics"],
];

const state = {
  run: null,
  tracks: {},          // name -> geometry
  shownTrack: null,
  poses: [],
  cameraWorker: null,
  evaluations: [],
  evaluation: null,    // the whole record drawn on the track
  pickedVersion: null, // a checkpoint the user clicked (null: the newest evaluation)
  checkpoints: [],
  view: null,          // metres -> pixels of the track canvas
};
window.racerView = state; // for a person's console

const $ = (id) => document.getElementById(id);

async function getJSON(path) {
  const r = await fetch(path, { cache: "no-store" });
  if (!r.ok) {
    let msg = `${path}: HTTP ${r.status}`;
    try { msg = (await r.json()).error || msg; } catch (e) { /* not JSON */ }
    throw new Error(msg);
  }
  return r.json();
}

function fmt(v) {
  // What the page shows of a number: 4 significant digits (the data-value attribute keeps it whole).
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  if (Math.abs(v) >= 1000) return v.toFixed(0);
  return String(Number(v.toPrecision(4)));
}

function fmtAxis(v) {
  // An axis label: short enough for the chart's margin.
  const a = Math.abs(v);
  if (a !== 0 && (a < 0.01 || a >= 1e5)) return v.toExponential(1);
  return String(Number(v.toPrecision(3)));
}

function setStatus(text, error) {
  const el = $("status");
  el.textContent = text;
  el.className = error ? "error" : "";
}

function esc(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
}

// --- the track ------------------------------------------------------------------------------------------------
async function showTrack(name) {
  if (!state.tracks[name]) state.tracks[name] = await getJSON(`api/track?name=${encodeURIComponent(name)}`);
  state.shownTrack = name;
  drawTrack();
}

function fitView(g, canvas) {
  const all = g.outer.concat(g.inner);
  const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const pad = 16;
  const s = Math.min((canvas.width - 2 * pad) / (x1 - x0 || 1), (canvas.height - 2 * pad) / (y1 - y0 || 1));
  const ox = (canvas.width - s * (x1 - x0)) / 2, oy = (canvas.height - s * (y1 - y0)) / 2;
  return { px: (x) => ox + s * (x - x0), py: (y) => canvas.height - (oy + s * (y - y0)), s };
}

function polyline(ctx, v, pts, close) {
  pts.forEach((p, i) => (i ? ctx.lineTo(v.px(p[0]), v.py(p[1])) : ctx.moveTo(v.px(p[0]), v.py(p[1]))));
  if (close) ctx.closePath();
}

function speedColour(t) { // matplotlib's "cool", as racer plot draws trajectories: cyan (slow) to magenta (fast)
  t = Math.max(0, Math.min(1, t));
  return `rgb(${Math.round(255 * t)},${Math.round(255 * (1 - t))},255)`;
}

function drawTrack() {
  const g = state.tracks[state.shownTrack];
  const canvas = $("track-canvas"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#3d6b35";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  if (!g) return;
  const v = (state.view = fitView(g, canvas));
  ctx.beginPath();
  polyline(ctx, v, g.outer, g.closed);
  if (g.closed) {
    polyline(ctx, v, g.inner.slice().reverse(), true);
  } else {
    g.inner.slice().reverse().forEach((p) => ctx.lineTo(v.px(p[0]), v.py(p[1])));
    ctx.closePath();
  }
  ctx.fillStyle = "#555";
  ctx.fill("evenodd");
  ctx.strokeStyle = "#fff";
  ctx.lineWidth = 2;
  for (const border of [g.inner, g.outer]) { ctx.beginPath(); polyline(ctx, v, border, g.closed); ctx.stroke(); }
  ctx.setLineDash([6, 6]);
  ctx.strokeStyle = "#f2c500";
  ctx.lineWidth = 1;
  ctx.beginPath(); polyline(ctx, v, g.center, g.closed); ctx.stroke();
  ctx.setLineDash([]);
  drawLaps(ctx, v);
  drawCars();
}

function drawLaps(ctx, v) {
  // The shown evaluation's trials on this track, each step's segment coloured by its speed.
  const e = state.evaluation;
  const legend = [];
  if (e && e.trials) {
    const trials = e.trials.filter((t) => t.track === state.shownTrack && t.trajectory && t.trajectory.length > 1);
    const speeds = trials.flatMap((t) => t.trajectory.map((p) => p[2]));
    const lo = speeds.reduce((a, b) => Math.min(a, b), Infinity), hi = speeds.reduce((a, b) => Math.max(a, b), -Infinity);
    ctx.lineWidth = 2.5;
    for (const t of trials) {
      for (let i = 1; i < t.trajectory.length; i++) {
        const a = t.trajectory[i - 1], b = t.trajectory[i];
        ctx.strokeStyle = speedColour((b[2] - lo) / (hi - lo || 1));
        ctx.beginPath(); ctx.moveTo(v.px(a[0]), v.py(a[1])); ctx.lineTo(v.px(b[0]), v.py(b[1])); ctx.stroke();
      }
    }
    if (trials.length) {
      legend.push(`<span>evaluation v${e.version}: ${trials.length} trials, speed ` +
        `<span class="swatch" style="background:${speedColour(0)}"></span>${fmt(lo)} – ` +
        `<span class="swatch" style="background:${speedColour(1)}"></span>${fmt(hi)} m/s</span>`);
    }
  }
  state.lapLegend = legend.join("");
  drawLegend();
}

function drawCars() {
  const canvas = $("cars-canvas"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const v = state.view;
  if (!v) return;
  for (const p of state.poses) {
    if (p.track !== state.shownTrack) continue;
    const x = v.px(p.x), y = v.py(p.y), h = (p.heading * Math.PI) / 180;
    ctx.fillStyle = COLOURS[p.index % COLOURS.length];
    ctx.strokeStyle = "#000";
    ctx.lineWidth = 1;
    ctx.beginPath(); ctx.arc(x, y, 7, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    ctx.strokeStyle = "#fff";
    ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + 12 * Math.cos(h), y - 12 * Math.sin(h)); ctx.stroke();
  }
  drawLegend();
}

function drawLegend() {
  const cars = state.poses.map((p) =>
    `<span><span class="swatch" style="background:${COLOURS[p.index % COLOURS.length]}"></span>` +
    `worker ${p.index}${p.track !== state.shownTrack ? ` (on ${esc(p.track)})` : ""}</span>`).join("");
  $("track-legend").innerHTML = cars + (state.lapLegend || "");
}

// --- live: poses, workers, camera --------------------------------------------------------------------------------
async function pollLive() {
  try {
    const live = await getJSON("api/live");
    state.poses = live.poses;
    const t = live.trainer;
    let line = live.live ? "live" : "finished run (no Redis): the run as stored";
    if (live.error) line = live.error;
    if (t) line += ` · iteration ${t.iteration} · v${t.policy_version} · ${fmt(t.steps_per_s)} env steps/s`;
    if (live.live && !live.error) line += ` · ${live.poses.length} cars shown`;
    setStatus(line, Boolean(live.error));
    drawCars();
    showWorkers(live.poses, live.time);
    updateCameraChoices(live);
  } catch (e) {
    setStatus(`cannot reach racer view: ${e.message}`, true);
  }
  setTimeout(pollLive, LIVE_MS);
}

function showWorkers(poses, now) {
  const body = $("workers").tBodies[0];
  body.innerHTML = poses.map((p) =>
    `<tr data-worker="${esc(p.worker_id)}" data-index="${p.index}">` +
    `<td><span class="swatch" style="background:${COLOURS[p.index % COLOURS.length]}"></span>${esc(p.worker_id)}</td>` +
    `<td>${p.index}</td><td>${esc(p.track)}${p.reversed ? " (rev.)" : ""}</td>` +
    `<td class="x" data-value="${p.x}">${p.x.toFixed(2)}</td><td class="y" data-value="${p.y}">${p.y.toFixed(2)}</td>` +
    `<td>${p.speed.toFixed(2)}</td><td>${p.progress.toFixed(1)}</td><td>${p.steps}</td><td>${esc(p.status)}${now - p.time > 2 ? " (waiting)" : ""}</td></tr>`
  ).join("");
}

function updateCameraChoices(live) {
  const select = $("camera-select");
  const ids = live.poses.map((p) => p.worker_id);
  const have = Array.from(select.options).map((o) => o.value);
  if (ids.join("\n") !== have.join("\n") && !(ids.length === 0 && have.length)) {
    select.innerHTML = ids.map((id, i) => `<option value="${esc(id)}">worker ${live.poses[i].index}: ${esc(id)}</option>`).join("");
    if (state.cameraWorker && ids.includes(state.cameraWorker)) select.value = state.cameraWorker;
  }
  if (!state.cameraWorker && ids.length) chooseCamera(ids[0]);
  const pose = live.poses.find((p) => p.worker_id === state.cameraWorker);
  drawLidar(pose && pose.lidar);
  const note = !live.live ? "no live run: the camera shows only while a run trains"
    : !ids.length ? "waiting for the workers' poses (they publish within a second of a page opening)"
    : pose && pose.frames === 0 ? "waiting for the first frame" : "";
  $("camera-note").textContent = note;
}

function chooseCamera(id) {
  state.cameraWorker = id;
  $("camera-select").value = id;
  $("camera").src = `api/camera?worker=${encodeURIComponent(id)}`;
}

function drawLidar(lidar) {
  const canvas = $("lidar-canvas");
  canvas.hidden = !lidar;
  if (!lidar) return;
  const ctx = canvas.getContext("2d"), c = canvas.width / 2, r = c - 8;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const hi = Math.max(...lidar, 1e-6);
  // DeepRacer's scan: sample 0 looks 30° left of ahead, the samples sweep anticlockwise to 30° right of ahead
  // (sim/lidar.py); ahead is up. Fewer values (a sector LiDAR) split the same 300° arc.
  const n = lidar.length, step = (300 / n) * (Math.PI / 180);
  ctx.strokeStyle = "#444";
  ctx.beginPath(); ctx.arc(c, c, r, 0, 2 * Math.PI); ctx.stroke();
  ctx.fillStyle = "rgba(66, 212, 244, 0.6)";
  ctx.beginPath(); ctx.moveTo(c, c);
  lidar.forEach((value, i) => {
    for (const k of [0, 1]) {
      const a = Math.PI / 2 + Math.PI / 6 + (i + k) * step; // from up (ahead), anticlockwise on screen
      ctx.lineTo(c + (r * value) / hi * Math.cos(a), c - (r * value) / hi * Math.sin(a));
    }
  });
  ctx.closePath(); ctx.fill();
  ctx.fillStyle = "#fff";
  ctx.fillRect(c - 3, c - 5, 6, 10);
}

// --- the store: charts, checkpoints, evaluations -----------------------------------------------------------------
async function pollStore() {
  try {
    if (!state.run.action_space) showRun(await getJSON("api/run")); // racer train --view: stored after the start
    const [metrics, checkpoints, evaluations] = await Promise.all([
      getJSON("api/metrics"), getJSON("api/checkpoints"), getJSON("api/evaluations"),
    ]);
    state.checkpoints = checkpoints;
    state.evaluations = evaluations;
    drawCharts(metrics, evaluations);
    showCheckpoints(checkpoints, evaluations);
    await showEvaluation();
  } catch (e) {
    setStatus(`store: ${e.message}`, true);
  }
  setTimeout(pollStore, STORE_MS);
}

function series(key, source, metrics, evaluations) {
  if (source === "metrics") {
    return metrics.filter((r) => typeof r[key] === "number").map((r) => [r.iteration, r[key]]);
  }
  if (key === "completion") return evaluations.map((e) => [e.version, 100 * e.completion_rate]);
  return evaluations.filter((e) => typeof e[key] === "number").map((e) => [e.version, e[key]]);
}

function drawCharts(metrics, evaluations) {
  $("iterations").textContent = metrics.length ? `${metrics.length} iterations, ${metrics[metrics.length - 1].env_steps} env steps` : "no iteration yet";
  const box = $("charts");
  if (!box.children.length) {
    box.innerHTML = CHARTS.map(([key, title]) =>
      `<div class="chart" id="chart-${key}"><div class="title"><span>${title}</span>` +
      `<span class="last" data-key="${key}"></span></div><svg viewBox="0 0 300 110" preserveAspectRatio="none"></svg></div>`).join("");
  }
  for (const [key, , source] of CHARTS) {
    const pts = series(key, source, metrics, evaluations);
    const chart = $(`chart-${key}`);
    const last = chart.querySelector(".last");
    const xLabel = source === "metrics" ? "iteration" : "checkpoint";
    if (pts.length) {
      const [x, y] = pts[pts.length - 1];
      last.textContent = fmt(y);
      last.dataset.value = String(y);
      last.dataset.x = String(x);
      last.title = `${xLabel} ${x}`;
    } else {
      last.textContent = "–";
      delete last.dataset.value;
      delete last.dataset.x;
    }
    last.dataset.points = String(pts.length);
    chart.querySelector("svg").innerHTML = svgLine(pts, xLabel);
  }
}

function svgLine(pts, xLabel) {
  if (!pts.length) return `<text x="150" y="58" text-anchor="middle">no data yet</text>`;
  const W = 300, H = 110, L = 40, R = 4, T = 6, B = 16;
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  if (y1 === y0) { const d = Math.abs(y0) * 0.1 || 1; y0 -= d; y1 += d; }
  const px = (x) => L + ((x - x0) / (x1 - x0)) * (W - L - R), py = (y) => T + (1 - (y - y0) / (y1 - y0)) * (H - T - B);
  const line = pts.map((p) => `${px(p[0]).toFixed(1)},${py(p[1]).toFixed(1)}`).join(" ");
  const dots = pts.length <= 60 ? pts.map((p) => `<circle cx="${px(p[0]).toFixed(1)}" cy="${py(p[1]).toFixed(1)}" r="1.8" fill="#1f77b4"/>`).join("") : "";
  return `<line x1="${L}" y1="${H - B}" x2="${W - R}" y2="${H - B}" stroke="#ccc"/>` +
    `<line x1="${L}" y1="${T}" x2="${L}" y2="${H - B}" stroke="#ccc"/>` +
    `<text x="${L - 3}" y="${T + 8}" text-anchor="end">${fmtAxis(y1)}</text>` +
    `<text x="${L - 3}" y="${H - B}" text-anchor="end">${fmtAxis(y0)}</text>` +
    `<text x="${L}" y="${H - 3}">${fmtAxis(x0)}</text>` +
    `<text x="${W - R}" y="${H - 3}" text-anchor="end">${xLabel} ${fmtAxis(x1)}</text>` +
    `<polyline points="${line}" fill="none" stroke="#1f77b4" stroke-width="1.5"/>${dots}`;
}

function showCheckpoints(checkpoints, evaluations) {
  const byVersion = Object.fromEntries(evaluations.map((e) => [e.version, e]));
  const shown = state.evaluation ? state.evaluation.version : null;
  $("checkpoints").tBodies[0].innerHTML = checkpoints.slice().reverse().map((c) => {
    const e = byVersion[c.version];
    const badges = (c.best ? '<span class="badge best">best</span>' : "") + (c.latest ? '<span class="badge latest">latest</span>' : "");
    const saved = c.created ? new Date(c.created * 1000).toLocaleTimeString() : "–";
    return `<tr data-version="${c.version}" class="${c.version === shown ? "selected" : ""}">` +
      `<td>v${c.version}</td><td>${c.env_steps ?? "–"}</td><td>${saved}</td><td class="pointers">${badges}</td>` +
      `<td class="completion">${e ? fmt(100 * e.completion_rate) + " %" : "not evaluated"}</td>` +
      `<td>${e ? fmt(e.best_lap_s) : "–"}</td><td>${e ? fmt(e.score) : "–"}</td><td>${c.video ? "▶ mp4" : "–"}</td></tr>`;
  }).join("");
}

async function showEvaluation() {
  const versions = state.evaluations.map((e) => e.version);
  const want = state.pickedVersion ?? (versions.length ? versions[versions.length - 1] : null);
  if (want === null) {
    $("evaluation-title").textContent = "(no evaluation yet)";
    showVideo(state.pickedVersion);
    return;
  }
  if (!versions.includes(want)) {
    state.evaluation = null;
    $("evaluation-title").textContent = `v${want}: not evaluated`;
    $("trials").tBodies[0].innerHTML = "";
    drawTrack();
    showVideo(want);
    return;
  }
  if (!state.evaluation || state.evaluation.version !== want) {
    state.evaluation = await getJSON(`api/evaluation/${want}`);
    const e = state.evaluation;
    const trackNames = [...new Set(e.trials.map((t) => t.track))];
    if (!trackNames.includes(state.shownTrack) && trackNames.length && !state.poses.length) {
      await showTrack(trackNames[0]).catch(() => {});
    }
    $("evaluation-title").textContent = `v${e.version}: ${fmt(100 * e.completion_rate)} % of ${e.episodes} laps completed` +
      (e.best_lap_s != null ? `, best lap ${fmt(e.best_lap_s)} s` : "");
    $("trials").tBodies[0].innerHTML = e.trials.map((t) =>
      `<tr><td>${esc(t.track)}</td><td>${t.reverse ? "reverse" : "forward"}</td><td>${t.start_index}</td>` +
      `<td>${esc(t.status)}</td><td>${fmt(t.progress)}</td><td>${t.steps}</td><td>${t.lap_time_s != null ? fmt(t.lap_time_s) : "–"}</td></tr>`).join("");
    drawTrack();
    showCheckpoints(state.checkpoints, state.evaluations);
    showVideo(want);
  }
}

function showVideo(version) {
  const box = $("video-box");
  if (version === null || version === undefined) { box.innerHTML = ""; return; }
  if (box.dataset.version === String(version)) return;
  box.dataset.version = String(version);
  const c = state.checkpoints.find((k) => k.version === version);
  box.innerHTML = c && c.video
    ? `<video id="video" controls preload="metadata" src="api/video/${version}"></video>`
    : `<p id="video-none" class="note">The store has no video of checkpoint v${version}'s evaluation ` +
      `(racer eval --run-id ${esc(state.run.run_id)} --checkpoint ${version} --video lap.mp4 makes one; ` +
      `the page plays runs/${esc(state.run.run_id)}/videos/${String(version).padStart(9, "0")}.mp4).</p>`;
}

function showRun(run) {
  state.run = run;
  $("run-id").textContent = run.run_id;
  const sensors = run.action_space ? run.action_space.sensors.join(", ") : "(not stored yet)";
  $("run-info").textContent = `${run.store} · track ${run.track} · ${run.race_type} · sensors ${sensors}` +
    (run.live ? ` · Redis ${run.redis}` : " · no Redis");
}

// --- start ------------------------------------------------------------------------------------------------------
async function start() {
  try {
    state.run = await getJSON("api/run");
  } catch (e) {
    setStatus(`cannot read the run: ${e.message}`, true);
    return;
  }
  const run = state.run;
  showRun(run);
  const select = $("track-select");
  if (run.tracks.length > 1) {
    select.hidden = false;
    select.innerHTML = run.tracks.map((t) => `<option>${esc(t)}</option>`).join("");
    select.value = run.track;
    select.onchange = () => showTrack(select.value);
  }
  $("camera-select").onchange = (ev) => chooseCamera(ev.target.value);
  $("checkpoints").tBodies[0].onclick = (ev) => {
    const row = ev.target.closest("tr");
    if (!row) return;
    state.pickedVersion = Number(row.dataset.version);
    showEvaluation();
  };
  await showTrack(run.track).catch((e) => setStatus(`track: ${e.message}`, true));
  pollLive();
  pollStore();
}

start();
