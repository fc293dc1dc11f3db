// The fleet page: an SVG map (stations, vehicles moving live), the vehicles' table and the task
// list with filters. Polls /api/fleet every 0.5 s; map y grows upwards (VDA 5050), SVG's down.
"use strict";
(function () {
  const NS = "http://www.w3.org/2000/svg";
  const svg = document.getElementById("map");
  const markers = {};
  const OPEN = ["RAW", "ACTIVE", "ASSIGNED", "BEING_PROCESSED"];
  let site = null;
  let last = null;

  function el(tag, attrs, text) {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
    if (text !== undefined) e.textContent = text;
    return e;
  }
  const sy = y => site.height - y;

  function drawSite(s) {
    site = s;
    svg.setAttribute("viewBox", "-1 -1 " + (s.width + 2) + " " + (s.height + 2));
    svg.appendChild(el("rect", {x: 0, y: 0, width: s.width, height: s.height, class: "floor"}));
    for (const st of s.stations) {
      const g = el("g", {class: "station" + (st.charger ? " charger" : "") + (st.page ? " has-page" : ""),
                         id: "station-" + st.name, "data-x": st.x, "data-y": st.y});
      g.appendChild(el("rect", {x: st.x - 0.3, y: sy(st.y) - 0.3, width: 0.6, height: 0.6}));
      if (!st.name.startsWith("park-")) g.appendChild(el("text", {x: st.x, y: sy(st.y) + 0.9, class: "label"}, st.name));
      if (st.page) {
        const a = el("a", {href: "/stations/" + encodeURIComponent(st.name)});
        a.appendChild(g);
        svg.appendChild(a);
      } else {
        svg.appendChild(g);
      }
    }
  }

  function drawVehicles(vehicles) {
    const seen = new Set();
    for (const v of vehicles) {
      seen.add(v.key);
      let m = markers[v.key];
      if (!m) {
        m = el("g", {class: "vehicle", id: "vehicle-" + v.serial, "data-key": v.key});
        const body = el("g", {class: "heading"});
        body.appendChild(el("circle", {r: 0.45}));
        body.appendChild(el("line", {x1: 0, y1: 0, x2: 0.7, y2: 0}));  // its heading (theta)
        m.appendChild(body);
        m.appendChild(el("text", {class: "label", y: -0.6}, v.serial));
        svg.appendChild(m);
        markers[v.key] = m;
      }
      const placed = v.x !== null && v.y !== null;
      m.setAttribute("visibility", placed ? "visible" : "hidden");
      m.setAttribute("class", "vehicle " + (v.connectionState || "").toLowerCase() + (v.task ? " busy" : ""));
      if (placed) {
        m.setAttribute("data-x", v.x.toFixed(3));
        m.setAttribute("data-y", v.y.toFixed(3));
        m.setAttribute("transform", "translate(" + v.x.toFixed(3) + " " + sy(v.y).toFixed(3) + ")");
        // theta counts counter-clockwise with y up; SVG's y points down, so its rotation is the negative
        m.firstChild.setAttribute("transform", "rotate(" + (-v.theta * 180 / Math.PI).toFixed(1) + ")");
      }
    }
    for (const key of Object.keys(markers)) if (!seen.has(key)) { markers[key].remove(); delete markers[key]; }
  }

  function render(data, status) {
    const error = document.getElementById("filter-error");
    if (status === 400) { error.textContent = data.error; error.hidden = false; return; }
    error.hidden = true;
    if (status !== 200) { HMI.banner([{ok: false, error: data.error || ("HTTP " + status)}]); return; }
    last = data;
    HMI.banner([data.planner, data.manager]);
    if (site) drawVehicles(data.vehicles);
    HMI.fill(document.querySelector("#vehicles tbody"), tbody => {
      for (const v of data.vehicles) {
        const pos = v.x === null ? "no position heard" : v.x.toFixed(2) + ", " + v.y.toFixed(2);
        const label = v.key + " (" + (v.interface || "?") + (v.pinned ? ", pinned" : "") + ")";
        HMI.row(tbody, [label, v.connectionState, v.battery === null ? "—" : v.battery.toFixed(1) + " %", pos,
                        v.task ? v.task + " (" + v.taskState + ")" : "idle", v.step], {"data-vehicle": v.key});
      }
    });
    HMI.fill(document.querySelector("#refused tbody"), tbody => {
      for (const r of data.refused || []) HMI.row(tbody, [r.vehicle, r.reason], {"data-refused": r.vehicle});
    });
    HMI.sync(document.querySelector("#tasks tbody"), data.tasks, t => t.id,
             t => [t.id, t.job, t.lotlanTask, t.state, t.vehicle, t.step, t.updated],
             t => ({"data-task": t.id, "data-state": t.state}), withdrawCell);
  }

  function withdrawCell(tr, t) {  // the last cell: a Withdraw button while the task is open
    let cell = tr.children[7];
    if (!cell) { cell = document.createElement("td"); tr.appendChild(cell); }
    const button = cell.querySelector("button.withdraw");
    if (OPEN.includes(t.state) && !button) {
      const b = document.createElement("button");
      b.type = "button";
      b.className = "withdraw";
      b.textContent = "Withdraw";
      b.dataset.task = t.id;
      cell.appendChild(b);
    } else if (!OPEN.includes(t.state) && button) {
      button.remove();
    }
  }

  function url() {
    const q = new URLSearchParams({state: document.getElementById("filter-state").value,
                                   vehicle: document.getElementById("filter-vehicle").value});
    return "/api/fleet?" + q.toString();
  }

  document.getElementById("filters").addEventListener("submit", ev => ev.preventDefault());
  // one listener on the table (its body is replaced on every poll)
  document.getElementById("tasks").addEventListener("click", async ev => {
    const button = ev.target.closest("button.withdraw");
    if (!button || !window.confirm("Withdraw task " + button.dataset.task + "?")) return;
    button.disabled = true;
    const {status, body} = await HMI.post("/api/tasks/" + encodeURIComponent(button.dataset.task) + "/withdraw");
    const note = document.getElementById("task-message");
    note.textContent = status === 200 ? "task " + body.id + " " + body.state : "not withdrawn: " + (body.error || status);
    note.className = status === 200 ? "ok" : "error";
  });
  fetch("/api/site", {credentials: "same-origin"}).then(r => r.json()).then(s => { drawSite(s); HMI.poll(url, render); });
  window.hmiFleet = () => last;
})();
