// groundstation dashboard: draws the snapshots the local server pushes over /events (SSE).
"use strict";

const STALE_AFTER_S = 3.0;
const SVG_NS = "http://www.w3.org/2000/svg";
const STATE_TEXT = { clean: "clean", half_cycle: "½ cycle", slipped: "slipped", code_only: "code only" };

// Test hook and debugging aid: what the page received and drew.
const gs = (window.gsDashboard = {
  updates: 0, doc: null, rxAt: 0, errors: [], source: null, renderErrors: 0, badDocs: 0,
});

function $(id) { return document.getElementById(id); }

function el(tag, attrs, text) {
  const node = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, String(v));
  if (text !== undefined) node.textContent = text;
  return node;
}

function setText(id, text, cls) {
  const node = $(id);
  node.textContent = text;
  if (cls !== undefined) node.className = node.className.split(" ").filter(
    (c) => !["good", "bad", "warn", "alarm"].includes(c)).concat(cls ? [cls] : []).join(" ");
}

function num(v, digits) {
  return v === null || v === undefined ? "-" : Number(v).toFixed(digits || 0);
}

function pct(v) {
  return v === null || v === undefined ? "-" : (v * 100).toFixed(v >= 0.9995 ? 0 : 1) + "%";
}

function bytes(v) {
  if (v === null || v === undefined) return "-";
  const units = ["B", "kB", "MB", "GB", "TB"];
  let i = 0;
  while (v >= 1000 && i < units.length - 1) { v /= 1000; i += 1; }
  return v.toFixed(i === 0 ? 0 : 1) + " " + units[i];
}

// "77.9 of 270.6 GB": one unit when both figures have it (shorter, as a surveyor says it).
function bytesOf(part, whole) {
  const a = bytes(part), b = bytes(whole);
  const ua = a.split(" ")[1], ub = b.split(" ")[1];
  return ua !== undefined && ua === ub ? a.split(" ")[0] + " of " + b : a + " of " + b;
}

function duration(s) {
  if (s === null || s === undefined) return "-";
  s = Math.max(0, Math.floor(s));
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return (h ? h + ":" : "") + String(m).padStart(h ? 2 : 1, "0") + ":" + String(sec).padStart(2, "0");
}

// A time in ns as HH:MM:SS UTC; "--:--:--" for anything a Date cannot hold (the server
// checks ranges, this is the page's own guard).
function hms(ns) {
  const ms = Number(ns) / 1e6;
  const d = new Date(ms);
  return Number.isFinite(ms) && !Number.isNaN(d.getTime())
    ? d.toISOString().substring(11, 19) : "--:--:--";
}

// One panel drawn; a failure is counted and the other panels still draw.
function panel(name, fn, arg) {
  try { fn(arg); } catch (err) {
    gs.renderErrors += 1;
    gs.errors.push(name + ": " + String((err && err.message) || err));
    if (gs.errors.length > 50) gs.errors.shift();
  }
}

function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); }

// -- connection --------------------------------------------------------------------------

function selectedStation() {
  return new URLSearchParams(window.location.search).get("station") || "";
}

function connect() {
  if (gs.source) gs.source.close();
  const station = selectedStation();
  const url = "/events" + (station ? "?station=" + encodeURIComponent(station) : "");
  const source = new EventSource(url);
  gs.source = source;
  source.addEventListener("snapshot", (ev) => {
    let doc;
    try { doc = JSON.parse(ev.data); } catch (err) {
      gs.badDocs += 1; gs.errors.push(String(err)); return;
    }
    if (!doc || typeof doc !== "object" || !Array.isArray(doc.stations)) {
      gs.badDocs += 1; gs.errors.push("snapshot without a station list"); return;
    }
    gs.doc = doc;
    gs.rxAt = performance.now();
    gs.updates += 1;
    render(doc);
  });
  // EventSource reconnects by itself (the server asks for 1 s); the badge says meanwhile.
  source.onerror = () => { refreshBadge(); };
}

$("station").addEventListener("change", (ev) => {
  const params = new URLSearchParams(window.location.search);
  params.set("station", ev.target.value);
  window.history.replaceState(null, "", "?" + params.toString());
  connect();
});

// -- header ------------------------------------------------------------------------------

// One rule for the badge and the station selector: a session the daemon said finished reads
// finished at once; otherwise a status older than STALE_AFTER_S is stale, a fresh one live.
function stationState(hasStatus, ageS, finished) {
  if (!hasStatus) return "waiting";
  if (finished) return "finished";
  return ageS > STALE_AFTER_S ? "stale" : "live";
}

const STATION_MARK = { waiting: "  … no data", finished: "  ■ finished", stale: "  ✕ stale",
  live: "  ● live" };

function renderStations(doc) {
  const select = $("station");
  const names = doc.stations.map((s) => s.name);
  const wanted = doc.station || "";
  const existing = Array.from(select.options).map((o) => o.value);
  if (existing.join("\n") !== names.join("\n")) {
    clear(select);
    for (const name of names) {
      const opt = document.createElement("option");
      opt.value = name;
      opt.textContent = name;
      select.appendChild(opt);
    }
  }
  // the ages move on between pushes (none come once a daemon has gone): age them here
  const sinceRx = (performance.now() - gs.rxAt) / 1000;
  for (const opt of select.options) {
    const s = doc.stations.find((x) => x.name === opt.value);
    const state = !s ? null : stationState(s.has_status, (s.status_age_s || 0) + sinceRx,
      s.finished);
    // a finished session's alerts are history: its panel shows them as of the end
    const alerts = s && s.alerts && state !== "finished" ? "  ⚠" + s.alerts : "";
    const text = opt.value + (state ? STATION_MARK[state] : "") + alerts;
    if (opt.textContent !== text) opt.textContent = text;
  }
  if (wanted && select.value !== wanted) select.value = wanted;
}

function refreshBadge() {
  const badge = $("badge"), detail = $("badge-detail");
  const doc = gs.doc;
  // the clocks first: the detail takes the room they leave
  $("clock-time").textContent = new Date().toISOString().substring(11, 19) + " UTC";
  renderDataClock(doc && doc.view ? doc.view.data_clock : null,
    doc ? doc.server_time_s : null);
  const sinceRx = (performance.now() - gs.rxAt) / 1000;
  let state, text, info;
  if (!doc || sinceRx > STALE_AFTER_S) {
    state = doc ? "disconnected" : "waiting";
    text = doc ? "NO SERVER" : "WAITING";
    info = doc ? "dashboard server not answering for " + sinceRx.toFixed(0) + " s (retrying)"
      : "connecting to the dashboard server";
  } else if (!doc.view) {
    state = "waiting"; text = "WAITING"; info = "no station on the bus yet";
  } else if (!doc.view.has_status) {
    state = "waiting"; text = "WAITING";
    info = "no status from " + doc.view.station + " yet" + (doc.view.alive ? " (daemon up)" : "");
  } else {
    const age = (doc.view.status_age_s || 0) + sinceRx;
    const st = stationState(true, age, doc.view.finished);
    if (st === "finished") {
      // A normal end of session is not a failure (no red STALE, no "daemon gone").
      state = "finished"; text = "SESSION FINISHED";
      info = "the daemon ended the session normally · values are the last ones";
    } else if (st === "stale") {
      state = "stale"; text = "STALE";
      info = "no status for " + age.toFixed(0) + " s" +
        (doc.view.alive === false ? " · daemon gone" : "") + " · values are old";
    } else {
      state = "live"; text = "LIVE";
      // the rate first: on a small screen the session id is hidden (.sid), the rate stays
      const rate = doc.view.rate_hz ? doc.view.rate_hz + " Hz" : "";
      const sid = doc.view.session_id || "";
      info = [rate, sid && rate ? " · " : "", sid];
    }
  }
  badge.className = "badge " + state;
  badge.textContent = text;
  if (Array.isArray(info)) {
    const [rate, sep, sid] = info;
    const span = document.createElement("span");
    span.className = "sid";
    span.textContent = sep + "session " + sid;
    detail.replaceChildren(document.createTextNode(rate));
    if (sid) detail.appendChild(span);
    detail.title = rate + sep + sid;
  } else {
    detail.textContent = info;
    detail.title = info;
  }
  // live, the rate stays whole: the session id (also in the session panel) goes when the
  // header has no room for it
  detail.classList.remove("no-sid");
  if (detail.scrollWidth > detail.clientWidth + 1) detail.classList.add("no-sid");
  document.body.dataset.state = state;
  if (doc) renderStations(doc);
}

// The data's time beside the computer's clock when the two are far apart (a replay, a
// simulated flight): the marks, the events and the timeline run on the data's time.
const DATA_CLOCK_APART_S = 60;

function apartText(s) {
  s = Math.round(Math.abs(s));
  const d = Math.floor(s / 86400), h = Math.floor((s % 86400) / 3600), m = Math.floor((s % 3600) / 60);
  return d >= 2 ? d + " days" : d ? d * 24 + h + " h" : h ? h + " h " + String(m).padStart(2, "0") +
    " min" : m ? m + " min" : s + " s";
}

function renderDataClock(dc, serverS) {
  const node = $("data-clock");
  const behind = dc && typeof dc.unix_ms === "number" && typeof serverS === "number"
    ? serverS - dc.unix_ms / 1000 : null;
  const apart = behind !== null && Math.abs(behind) >= DATA_CLOCK_APART_S;
  node.hidden = !apart;
  $("clock").classList.toggle("two", apart);
  if (!apart) return;
  const text = dc.utc + " UTC";
  if ($("data-time").textContent !== text) $("data-time").textContent = text;
  node.title = "the receiver's time in the data (a replay or a simulated flight), " +
    apartText(behind) + (behind > 0 ? " behind" : " ahead of") + " this computer's clock: " +
    "the marks, the events and the timeline run on it";
}

// -- sky plot ----------------------------------------------------------------------------

function renderSky(sats) {
  const svg = $("sky");
  clear(svg);
  svg.appendChild(el("circle", { class: "ring outer", r: 100 }));
  for (const elev of [30, 60]) {
    svg.appendChild(el("circle", { class: "ring", r: (90 - elev) / 90 * 100 }));
    svg.appendChild(el("text", { class: "ring-label", x: 2, y: -(90 - elev) / 90 * 100 - 2 }, elev + "°"));
  }
  svg.appendChild(el("line", { class: "spoke", x1: -100, y1: 0, x2: 100, y2: 0 }));
  svg.appendChild(el("line", { class: "spoke", x1: 0, y1: -100, x2: 0, y2: 100 }));
  for (const [label, x, y] of [["N", 0, -110], ["E", 110, 0], ["S", 0, 110], ["W", -110, 0]]) {
    svg.appendChild(el("text", { class: "card", x: x, y: y }, label));
  }
  const unplaced = [];
  for (const s of sats) {
    if (s.elev_deg === null || s.azim_deg === null || s.elev_deg === undefined) {
      unplaced.push(s.sv);
      continue;
    }
    const r = (90 - Math.max(0, Math.min(90, s.elev_deg))) / 90 * 100;
    const az = s.azim_deg * Math.PI / 180;
    const x = r * Math.sin(az), y = -r * Math.cos(az);
    const g = el("g", { class: "sat-group", "data-sv": s.sv, "data-state": s.state });
    const title = el("title", {}, s.sv + " · " + STATE_TEXT[s.state] + " · " + s.cno_dbhz +
      " dBHz · el " + s.elev_deg + "° az " + s.azim_deg + "° · slips " + s.slips);
    g.appendChild(title);
    g.appendChild(el("circle", { class: "sat " + s.state, cx: x.toFixed(1), cy: y.toFixed(1), r: 10.5 }));
    g.appendChild(el("text", { class: "sat-label " + s.state, x: x.toFixed(1), y: y.toFixed(1) },
      s.sv.replace(/^G/, "").replace(/\/.*/, "")));
    svg.appendChild(g);
  }
  const notes = [];
  if (unplaced.length) notes.push("no position yet: " + unplaced.join(" "));
  const ppk = gs.doc && gs.doc.view ? gs.doc.view.ppk : null;
  if (ppk && ppk.unidentified_text) notes.push(ppk.unidentified_text);
  $("sky-note").textContent = notes.join(" · ");
}

// -- C/N0 bars ---------------------------------------------------------------------------

// Drawn in the element's own pixels (no stretched text) with every label measured: a row of
// labels wider than a bar's slot (22 satellites on a 1024 px screen) turns upright, so no two
// labels overlap however many satellites there are.
function renderCno(sats) {
  const svg = $("cno");
  clear(svg);
  const box = svg.getBoundingClientRect();
  const W = Math.round(box.width) || 520, H = Math.round(box.height) || 300;
  svg.setAttribute("viewBox", "0 0 " + W + " " + H);
  const list = sats.slice().sort((a, b) => a.sv.localeCompare(b.sv));
  const lo = 20, hi = 55, left = 30;
  const slot = (W - left) / Math.max(list.length, 8), w = slot * 0.76;
  const rows = list.map((s) => ({
    s: s,
    value: el("text", { class: "bar-value" }, num(s.cno_dbhz)),
    sv: el("text", { class: "bar-sv" }, s.sv),
    clean: el("text", { class: "bar-clean" }, s.state === "code_only" ? "—" :
      s.half_cycle_unresolved ? "½" : num(s.clean_phase_s) + "s"),
  }));
  for (const r of rows) svg.append(r.value, r.sv, r.clean);
  // a row's widest label and its font, measured; upright when it does not fit its slot, then
  // in a font whose line is no thicker than the slot
  const size = (kind) => {
    let wide = 0, thick = 0, font = 12;
    for (const r of rows) {
      const b = r[kind].getBBox();
      wide = Math.max(wide, b.width);
      thick = Math.max(thick, b.height);
      font = parseFloat(getComputedStyle(r[kind]).fontSize) || font;
    }
    if (wide + 3 <= slot) return { upright: false, font: font, extent: font };
    const scale = Math.min(1, (slot - 2) / Math.max(1, thick));
    if (scale < 1) for (const r of rows) r[kind].style.fontSize = (font * scale).toFixed(2) + "px";
    return { upright: true, font: font * scale, extent: wide * scale };
  };
  const value = size("value"), sv = size("sv"), clean = size("clean");
  const top = value.extent + 6, gap = 4;
  const bottom = Math.max(top + 20, H - sv.extent - clean.extent - 3 * gap);
  const y = (v) => bottom - (Math.max(lo, Math.min(hi, v)) - lo) / (hi - lo) * (bottom - top);
  for (const ref of [30, 40, 50]) {
    svg.insertBefore(el("line", { class: "ref", x1: left - 4, x2: W, y1: y(ref), y2: y(ref) }),
      svg.firstChild);
    svg.insertBefore(el("text", { class: "ref-label", x: 0, y: y(ref) + 4 }, String(ref)),
      svg.firstChild);
  }
  if (!list.length) {
    svg.appendChild(el("text", { class: "bar-value", x: W / 2, y: H / 2 }, "no satellites"));
    return;
  }
  // a label at (cx, yy): level and centred, or upright reading upwards, hanging from yy down
  // (below the bars) or standing on it (above a bar)
  const place = (node, how, cx, yy, hang) => {
    if (!how.upright) {
      node.setAttribute("x", cx.toFixed(1));
      node.setAttribute("y", (hang ? yy + how.font * 0.8 : yy).toFixed(1));
      return;
    }
    node.setAttribute("x", cx.toFixed(1));
    node.setAttribute("y", yy.toFixed(1));
    node.style.textAnchor = hang ? "end" : "start";
    node.style.dominantBaseline = "central";
    node.setAttribute("transform", "rotate(-90 " + cx.toFixed(1) + " " + yy.toFixed(1) + ")");
  };
  rows.forEach((r, i) => {
    const s = r.s, x = left + i * slot + slot * 0.12, cx = x + w / 2;
    const v = s.cno_dbhz === null ? lo : s.cno_dbhz;
    svg.insertBefore(el("rect", { class: "bar " + s.state, x: x, y: y(v), width: w,
      height: Math.max(1, bottom - y(v)), "data-sv": s.sv }), r.value);
    place(r.value, value, cx, y(v) - gap, false);
    place(r.sv, sv, cx, bottom + gap, true);
    place(r.clean, clean, cx, bottom + sv.extent + 2 * gap, true);
  });
}

// -- PPK gauge ---------------------------------------------------------------------------

function arc(r, a0, a1) {
  // angles in [0, 1] along the upper half circle, left to right
  const p = (a) => [(-Math.cos(a * Math.PI) * r).toFixed(2), (-Math.sin(a * Math.PI) * r).toFixed(2)];
  const [x0, y0] = p(a0), [x1, y1] = p(a1);
  return "M " + x0 + " " + y0 + " A " + r + " " + r + " 0 0 1 " + x1 + " " + y1;
}

function renderPpk(ppk) {
  const svg = $("ppk");
  clear(svg);
  const ready = ppk.ready === null || ppk.ready === undefined ? 0 : ppk.ready;
  const full = Math.max(12, (ppk.tracked || 0), ppk.min * 2);
  const ok = ready >= ppk.min;
  svg.appendChild(el("path", { class: "gauge-bg", d: arc(80, 0, 1) }));
  if (ready > 0) {
    svg.appendChild(el("path", { class: "gauge-fg " + (ok ? "good" : "bad"),
      d: arc(80, 0, Math.min(1, ready / full)) }));
  }
  const m = ppk.min / full;
  const mx = -Math.cos(m * Math.PI), my = -Math.sin(m * Math.PI);
  svg.appendChild(el("line", { class: "gauge-min", x1: (mx * 64).toFixed(1), y1: (my * 64).toFixed(1),
    x2: (mx * 96).toFixed(1), y2: (my * 96).toFixed(1) }));
  setText("ppk-ready", ppk.ready === null || ppk.ready === undefined ? "-" : String(ppk.ready),
    ok ? "good" : "bad");
  $("ppk-min").textContent = String(ppk.min);
  // what the number counts, in watch's words; the condition in the small print of a heading
  const title = $("ppk-title"), cut = ppk.label.indexOf(" (");
  if (title.textContent !== ppk.label) {
    const sub = document.createElement("span");
    sub.className = "sub";
    sub.textContent = cut < 0 ? "" : ppk.label.slice(cut);
    title.replaceChildren(document.createTextNode(cut < 0 ? ppk.label : ppk.label.slice(0, cut)),
      sub);
  }
  // "of 10 tracked (2 below the 15° elevation mask)": why the number is lower, in watch's words
  $("ppk-detail").textContent = "of " + (ppk.tracked_text || num(ppk.tracked) + " tracked") +
    " · half-cycle " +
    (ppk.half_cycle_fraction === null || ppk.half_cycle_fraction === undefined ? "-" :
      (ppk.half_cycle_fraction * 100).toFixed(0) + "%");
}

// -- marks -------------------------------------------------------------------------------

function renderMarks(ms) {
  setText("marks-count", num(ms.marks));
  setText("marks-missed", num(ms.missed), ms.missed ? "alarm" : "good");
  setText("marks-indrop", num(ms.in_dropout), ms.in_dropout ? "alarm" : "good");
  setText("marks-rate", num(ms.rate_per_min, 1));
  setText("marks-last", ms.last_utc ? ms.last_utc + (ms.last_age_s !== null ?
    "  (" + num(ms.last_age_s, 0) + " s ago)" : "") : "none yet");
  // why the missed ones were lost: the radio (fix the link) or the receiver (trigger rate)
  $("marks-detail").textContent = (ms.missed ? "missed: " + num(ms.lost_on_link || 0) +
    " lost on the radio, " + num(ms.not_reported || 0) + " not reported by the receiver · " :
    "") + "count " + num(ms.last_count) + " · pulse " +
    num(ms.last_pulse_width_ms, 1) + " ms · duplicates " + num(ms.duplicates) +
    " · 2 in one epoch " + num(ms.multi_in_epoch) + " · mark messages here " + num(ms.received);
}

// -- link timeline -----------------------------------------------------------------------

function renderLink(view) {
  const link = view.link || {};
  const c60 = link.completeness_60s;
  setText("link-60", pct(c60), c60 === null || c60 === undefined ? "" : c60 >= 0.98 ? "good" : "bad");
  setText("link-session", pct(link.completeness_session));
  setText("link-dropouts", num(link.dropouts) + " (" + num(link.missing_epochs) + " ep)",
    link.dropouts ? "warn" : "");
  const ongoing = !view.finished && (view.timeline.dropouts || []).find((d) => d[2]);
  if (ongoing) {
    const secs = ongoing[1] - ongoing[0];
    setText("link-now", "DROPOUT " + num(secs, 1) + " s", "alarm");
  } else if (view.finished) {
    setText("link-now", "ended", "");  // not "receiving": nothing comes after the end
  } else {
    setText("link-now", link.epochs ? "receiving" : "-", link.epochs ? "good" : "");
  }
  setText("link-rate", view.rate_hz ? view.rate_hz + " Hz" : "-");
  setText("link-bps", num(link.bytes_per_s));
  setText("link-damaged", num(link.damaged_frames), link.damaged_frames ? "warn" : "");
  const src = link.source_connected;
  setText("link-source", src === false ? "LOST" : src ? "connected" : "-", src === false ? "alarm" : "");
  renderTimeline(view.timeline);
}

function renderTimeline(tl) {
  const svg = $("timeline");
  clear(svg);
  const W = 1320;
  const total = tl.span_s + tl.bucket_s;
  const x = (t) => Math.max(0, Math.min(W, t / total * W));
  for (let m = 60; m < total; m += 60) {
    svg.appendChild(el("line", { class: "tl-grid", x1: x(m), x2: x(m), y1: 0, y2: 96 }));
  }
  if (tl.start_t_gps_ns === null) return;
  const bw = tl.bucket_s / total * W;
  if (tl.first_s > 0) {  // before the session's first epoch: nothing was expected
    svg.appendChild(el("rect", { class: "tl-before", x: 0, y: 14, width: x(tl.first_s), height: 50 }));
  }
  tl.buckets.forEach(([expected, received], i) => {
    const x0 = i * bw;
    if (expected === 0) return;
    const frac = received / expected;
    const hOk = 50 * frac;
    svg.appendChild(el("rect", { class: "tl-missing", x: x0 + 0.5, y: 14, width: bw - 1, height: 50 - hOk }));
    svg.appendChild(el("rect", { class: "tl-ok", x: x0 + 0.5, y: 14 + 50 - hOk, width: bw - 1, height: hOk,
      "data-expected": expected, "data-received": received }));
  });
  for (const [a, b, ongoing, missing] of tl.dropouts) {
    svg.appendChild(el("rect", { class: "dropout" + (ongoing ? " ongoing" : ""), x: x(a), y: 66,
      width: Math.max(4, x(b) - x(a)), height: 16, "data-missing": missing, "data-start": a }));
  }
  for (const [a, b, ongoing] of tl.outages) {
    svg.appendChild(el("rect", { class: "outage" + (ongoing ? " ongoing" : ""), x: x(a), y: 84,
      width: Math.max(4, x(b) - x(a)), height: 12 }));
  }
  for (const [t, inDrop] of tl.marks) {
    svg.appendChild(el("line", { class: "mark" + (inDrop ? " in-dropout" : ""), x1: x(t), x2: x(t), y1: 0, y2: 12 }));
  }
  svg.appendChild(el("line", { class: "tl-now", x1: x(tl.now_s), x2: x(tl.now_s), y1: 0, y2: 96 }));
}

// -- session, alerts, events -------------------------------------------------------------

function renderSession(s) {
  const rec = $("rec");
  const recording = s.file && s.state !== "finished";
  rec.textContent = recording ? "● RECORDING" : s.state === "finished" ? "■ finished" : "not recording";
  rec.className = "rec" + (recording ? " on" : "");
  const file = $("sess-file");
  file.textContent = s.file ? s.file.split("/").pop() : "-";
  file.title = (s.file || "") + (s.id ? "\nsession " + s.id : "");
  $("sess-duration").textContent = duration(s.duration_s);
  $("sess-bytes").textContent = bytes(s.size_bytes) + (s.bytes_in !== null && s.bytes_in !== undefined
    ? " · in " + bytes(s.bytes_in) : "");
  const low = s.disk_free_bytes !== null && s.disk_free_bytes !== undefined && s.disk_free_bytes < 1e9;
  setText("sess-disk", s.disk_free_bytes === null || s.disk_free_bytes === undefined ? "unknown (remote)" :
    bytesOf(s.disk_free_bytes, s.disk_total_bytes), low ? "alarm" : "");
}

function renderReport(r) {
  // The latest flight report the solver announced (served by the dashboard at /report).
  const td = $("sess-report");
  clear(td);
  if (!r) { td.textContent = "-"; $("verdict").hidden = true; return; }
  const link = (href, text) => {
    const a = document.createElement("a");
    a.href = href; a.target = "_blank"; a.rel = "noopener"; a.textContent = text;
    return a;
  };
  const a = link(r.url, "latest: " + r.flight);
  td.appendChild(a);
  // go / no-go before packing up (all marks fixed, or what to fly again): beside the alerts,
  // where the whole width shows it
  const v = $("verdict");
  v.hidden = !r.verdict;
  if (r.verdict) {
    v.className = "verdict " + (r.verdict.ok ? "go" : "nogo");
    v.textContent = (r.verdict.ok ? "GO: " : "FLY AGAIN: ") + r.verdict.text;
  }
  if (r.pdf) {
    td.appendChild(document.createTextNode(" · "));
    td.appendChild(link(r.url + "&format=pdf", "PDF"));
  }
}

const RTK_QUALITIES = new Set(["fix", "float", "dgps", "single", "none"]);
const rtkClass = (q) => "rtk-" + (RTK_QUALITIES.has(q) ? q : "none");  // colours: style.css

function renderRtk(r) {
  // The live position (groundstation rtk / the demo's engine): quality, its fixed share over
  // the last minute, ratio, satellites, base age, sigma; the track in east/north metres from
  // its first point, one path per run of a quality; each mark where it fell, in that colour.
  const q = $("rtk-q"), text = $("rtk-text"), svg = $("rtk-track");
  clear(svg);
  $("rtk-alert").hidden = !(r && r.latest && r.latest.alert === "fix_lost");
  if (!r || !r.latest) {
    q.className = "none"; q.textContent = "-"; text.textContent = "no live positions";
    return;
  }
  const m = r.latest;
  q.className = m.quality; q.textContent = m.quality;
  const parts = [];
  if (r.fixed_share !== null && r.fixed_share !== undefined)
    parts.push("fixed " + Math.round(r.fixed_share * 100) + "% of the last " +
               Math.round(r.window_s) + " s");
  if (m.quality === "none") parts.push(m.why || "no position");
  else {
    // fix-and-hold reports its held ambiguities with ratio 999.9
    // 0: no ambiguity resolution tried at this epoch (a float)
    parts.push((m.ratio >= 999 ? "ambiguities held, " : m.ratio > 0 ? "ratio " + num(m.ratio, 1) + ", " : "") + m.sats + " sats");
    if (typeof m.age_s === "number") parts.push("base age " + num(m.age_s, 1) + " s");
    if (m.sd_enu_m) parts.push("σ " + m.sd_enu_m.map(v => num(v * 100, 1)).join("/") + " cm");
  }
  text.textContent = parts.join(" · ");
  const pts = r.track || [];
  if (pts.length < 2) return;
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const [e, n] of pts) { x0 = Math.min(x0, e); x1 = Math.max(x1, e);
                              y0 = Math.min(y0, n); y1 = Math.max(y1, n); }
  const w = Math.max(x1 - x0, y1 - y0, 1) * 1.08, cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  svg.setAttribute("viewBox", `${cx - w / 2} ${-cy - w / 2} ${w} ${w}`);
  const stroke = w / 150;
  let run = [], runQ = null;
  const flush = () => {
    if (run.length > 1) svg.appendChild(el("polyline", {
      points: run.map(([e, n]) => `${e},${-n}`).join(" "), fill: "none",
      class: "rtk-path " + rtkClass(runQ), "stroke-width": stroke}));
  };
  for (const p of pts) {
    if (p[2] !== runQ) { const last = run[run.length - 1]; flush();
                         run = last ? [last] : []; runQ = p[2]; }
    run.push(p);
  }
  flush();
  for (const [e, n, mq] of r.marks || []) {
    svg.appendChild(el("circle", {cx: e, cy: -n, r: stroke * 2.5, class: "rtk-mark " + rtkClass(mq),
                                  "stroke-width": stroke * 1.2}));
  }
}

function renderAlerts(view) {
  const alerts = view.alerts;
  const ended = Boolean(view.finished);  // the alerts standing when the session ended
  $("alerts-title").textContent = ended ? "Alerts at the end" : "Alerts";
  const ul = $("alerts");
  clear(ul);
  for (const a of alerts) {
    const li = document.createElement("li");
    li.textContent = "⚠ " + a;
    if (ended) li.className = "ended";
    ul.appendChild(li);
  }
  if (!alerts.length) {
    const li = document.createElement("li");
    li.className = "none";
    li.textContent = "no alerts";
    ul.appendChild(li);
  }
  const count = $("alert-count");
  count.textContent = alerts.length + (alerts.length === 1 ? " alert" : " alerts") +
    (ended && alerts.length ? " at end" : "");
  count.className = "alert-count " + (!alerts.length ? "none" : ended ? "ended" : "some");
  // Missed marks stay raised until acknowledged: the daemon clears them for every view (a
  // finished session's daemon is gone: nothing to acknowledge).
  $("ack").hidden = ended || !alerts.some((a) => a.indexOf("time mark") >= 0);
}

function acknowledge() {
  const station = selectedStation() || (gs.doc && gs.doc.view ? gs.doc.view.station : "");
  if (!station) return;
  fetch("/api/ack?station=" + encodeURIComponent(station) + "&alert=marks_missed",
    { method: "POST", headers: { "X-Groundstation": "ack" } })
    .catch(() => {});
}

function renderEvents(events) {
  const ul = $("events");
  clear(ul);
  for (const e of events) {
    const li = document.createElement("li");
    li.className = e.severity || "info";
    const t = document.createElement("span");
    t.className = "t";
    t.textContent = hms(e.t_host_ns || 0);
    li.appendChild(t);
    li.appendChild(document.createTextNode(e.message || e.kind || ""));
    li.title = e.kind || "";
    ul.appendChild(li);
  }
}

// -- the whole page ----------------------------------------------------------------------

function renderRejected(view) {
  const n = (view && view.rejected) || 0;
  const bad = n + gs.renderErrors;
  const node = $("rejected");
  node.textContent = bad ? bad + " bad messages dropped" : "";
  node.title = (view && view.last_rejection) || gs.errors[gs.errors.length - 1] || "";
}

function render(doc) {
  panel("stations", renderStations, doc);
  const view = doc.view;
  if (view) {
    panel("sky", renderSky, view.sats);
    panel("cno", renderCno, view.sats);
    panel("ppk", renderPpk, view.ppk);
    panel("marks", renderMarks, view.marks);
    panel("link", renderLink, view);
    panel("session", renderSession, view.session);
    panel("report", renderReport, view.report);
    panel("alerts", renderAlerts, view);
    panel("events", renderEvents, view.events);
    panel("rtk", renderRtk, view.rtk);
  }
  panel("rejected", renderRejected, view);
  panel("badge", refreshBadge);
}

$("ack").addEventListener("click", acknowledge);
window.setInterval(refreshBadge, 500);
connect();
