// The status page: polls /status.json every second and fills the cards. Vanilla JavaScript, no
// build step; every value is written with textContent (never as HTML).
"use strict";

const POLL_MS = 1000;
const STALE_S = 3;

function el(tag, text, cls) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = text;
  if (cls) node.className = cls;
  return node;
}

function num(value, digits) {
  return typeof value === "number" ? value.toFixed(digits) : "–";
}

function replace(id, children) {
  const node = document.getElementById(id);
  node.replaceChildren(...children);
}

function table(id, head, rows) {
  const thead = el("thead");
  const tr = el("tr");
  head.forEach((h) => tr.appendChild(el("th", h)));
  thead.appendChild(tr);
  const tbody = el("tbody");
  rows.forEach((cells) => {
    const row = el("tr");
    cells.forEach((c) => row.appendChild(c instanceof Node ? wrapCell(c) : el("td", c)));
    tbody.appendChild(row);
  });
  replace(id, [thead, tbody]);
}

function wrapCell(node) {
  const td = el("td");
  td.appendChild(node);
  return td;
}

function definitions(id, pairs) {
  const out = [];
  pairs.forEach(([k, v]) => { out.push(el("dt", k)); out.push(el("dd", v)); });
  replace(id, out);
}

function severityClass(severity) {
  return severity <= 3 ? "sev-err" : severity <= 4 ? "sev-warn" : "";
}

function messageItems(list) {
  if (!list || list.length === 0) return [el("li", "none", "muted")];
  return list.slice().reverse().map((m) =>
    el("li", `t=${num(m.time_s, 1)} s  ${m.source === "vehicle" ? "[vehicle] " : ""}${m.text}`, severityClass(m.severity)));
}

function render(s) {
  const c = s.connection || {};
  const v = s.vehicle;
  document.getElementById("connection").textContent =
    `${c.endpoint || ""} · system ${c.system_id ?? "?"} · profile ${c.profile || "?"}` +
    (s.companion && s.companion.version ? ` · v${s.companion.version}` : "");
  const pill = document.getElementById("link-state");
  const stale = !v || v.telemetry_age_s === null || v.telemetry_age_s > STALE_S;
  pill.textContent = stale ? "no telemetry" : "vehicle connected";
  pill.className = "pill " + (stale ? "stale" : "ok");

  if (v) {
    definitions("vehicle", [
      ["vehicle time", `${num(v.time_s, 1)} s`], ["mode", v.mode || "–"], ["armed", v.armed ? "yes" : "no"],
      ["speed (water)", `${num(v.speed_water, 2)} m/s`], ["heading", `${num(v.heading_deg, 1)}°`],
      ["depth", `${num(v.depth, 2)} m`], ["rudder", `${num(v.rudder_deg, 1)}°`], ["thrust", num(v.thrust, 2)],
    ]);
  }

  const p = s.procedure || {};
  const running = p.state === "running";
  document.getElementById("procedure-name").textContent = running ? `${p.name} running` : "idle";
  document.getElementById("procedure-bar").style.width = running && typeof p.progress_pct === "number" ? `${p.progress_pct}%` : "0";
  const last = p.last;
  document.getElementById("procedure-detail").textContent = running
    ? `started at t=${num(p.started_s, 1)} s` + (typeof p.progress_pct === "number" ? `, ${p.progress_pct} %` : "")
    : last ? `last: ${last.procedure} ${last.status}${last.reason ? " (" + last.reason + ")" : ""}` : "nothing run yet";

  const est = Object.entries(s.estimates || {});
  if (est.length) table("estimates", ["name", "value", "t (s)"], est.map(([k, e]) => [k, num(e.value, 4), num(e.time_s, 1)]));

  const m = s.models;
  if (m) {
    document.getElementById("models-title").textContent = `campaign ${m.campaign_id}: ${m.status}, ${m.accepted} accepted`;
    table("models", ["axis", "thrust", "try", "speed m/s", "R²", "accepted", "a22 / c22", "b2 / d2", "δ0"], m.runs.map((r) => [
      r.axis, num(r.thrust, 2), String(r.attempt), num(r.speed, 3), num(r.r2, 3),
      el("span", r.accepted ? "yes" : "no", r.accepted ? "yes" : "no"),
      num(r.model.a22 ?? r.model.c22, 4), num(r.model.b2 ?? r.model.d2, 4), num(r.model.delta0, 4),
    ]));
  }

  const sched = s.schedule;
  if (sched && sched.designs.length) {
    const parts = [el("p", sched.active ? "kept matched to speed" : "not scheduling", sched.active ? "yes" : "muted")];
    sched.designs.forEach((d) => {
      parts.push(el("p", `${d.kind} (campaign ${d.campaign_id}): ${d.law}`));
    });
    if (sched.last_write) {
      const w = sched.last_write;
      parts.push(el("p", `last write at t=${num(w.time_s, 1)} s, ${num(w.speed, 2)} m/s (${sched.writes} writes)`, "muted"));
    }
    replace("schedule", parts);
  }

  const g = s.gains;
  if (g && g.on_vehicle.length) table("gains", ["parameter", "value"], g.on_vehicle.map((x) => [x.name, num(x.value, 4)]));

  const h = s.health;
  if (h) {
    const parts = [el("p", h.on ? `watching against campaign ${h.reference_campaign}: ${h.windows_seen} windows` : h.reason,
      h.on ? "" : "muted")];
    if (h.alarm) parts.push(el("p", `ALARM: ${h.alarm.parameter} ${num(h.alarm.change_pct, 0)} % at t=${num(h.alarm.time_s, 0)} s`, "sev-err"));
    const used = (h.windows || []).filter((w) => w.used).slice(-4);
    used.forEach((w) => parts.push(el("p",
      `t=${num(w.t_end, 0)} s ${num(w.speed, 2)} m/s: a22×${num(w.ratio.a22, 2)} b2×${num(w.ratio.b2, 2)}`, "muted")));
    replace("health", parts);
  }

  const l = s.learning;
  if (l) {
    const parts = [el("p", l.phase ? `${l.phase}: ${l.reason}` : l.reason, l.on ? "" : "muted")];
    (l.bands || []).forEach((b) => parts.push(el("p",
      `${num(b.speed, 2)} m/s: ${b.windows} windows${b.validated ? ", validated" : ""}`, "muted")));
    (l.writes || []).forEach((w) => parts.push(el("p",
      `t=${num(w.time_s, 0)} s ${w.why}: ` + Object.entries(w.gains).map(([k, v]) => `${k} ${num(v, 3)}`).join(", "))));
    if (l.verdict) parts.push(el("p", `verdict: ${l.verdict.reason}`, l.verdict.keep ? "yes" : "sev-err"));
    const sp = l.speed;  // the speed loop (eq. L.4)
    if (sp) {
      parts.push(el("p", sp.on ? `speed loop ${sp.phase}: ${sp.reason}` : sp.reason, sp.on ? "" : "muted"));
      (sp.writes || []).forEach((w) => parts.push(el("p",
        `t=${num(w.time_s, 0)} s speed ${w.why}: ` + Object.entries(w.gains).map(([k, v]) => `${k} ${num(v, 3)}`).join(", "))));
      if (sp.verdict) parts.push(el("p", `speed verdict: ${sp.verdict.reason}`, sp.verdict.keep ? "yes" : "sev-err"));
    }
    replace("learning", parts);
  }

  replace("alarms", messageItems(s.alarms));
  replace("messages", messageItems(s.messages));

  const r = s.report;
  const report = document.getElementById("report");
  if (r) {
    const a = el("a", `campaign ${r.campaign_id}`);
    a.href = r.url;
    report.replaceChildren(a);
    report.className = "";
  }
}

async function poll() {
  try {
    const response = await fetch("/status.json", { cache: "no-store" });
    if (!response.ok) throw new Error(response.statusText);
    render(await response.json());
  } catch (err) {
    const pill = document.getElementById("link-state");
    pill.textContent = "companion not answering";
    pill.className = "pill stale";
  } finally {
    setTimeout(poll, POLL_MS);
  }
}

poll();
