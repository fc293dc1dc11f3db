// The overview renders itself from the status document (/api/status) and polls it (ETag).
(function () {
  "use strict";
  var POLL_MS = 2000;
  var etag = null;
  var current = JSON.parse(document.getElementById("initial-status").textContent);
  var cy = null;
  var graphKey = null;

  function el(tag, text, cls) {
    var e = document.createElement(tag);
    if (text !== undefined && text !== null) e.textContent = String(text);
    if (cls) e.className = cls;
    return e;
  }
  function uptime(startedAt) {
    if (!startedAt) return "-";
    var s = Math.max(0, Math.floor(Date.now() / 1000 - startedAt));
    if (s < 60) return s + "s";
    if (s < 3600) return Math.floor(s / 60) + "m" + (s % 60) + "s";
    return Math.floor(s / 3600) + "h" + Math.floor((s % 3600) / 60) + "m";
  }
  function fill(id, rows, cells) {
    var body = document.querySelector("#" + id + " tbody");
    var out = document.createDocumentFragment();
    rows.forEach(function (row) {
      var tr = el("tr");
      cells(row).forEach(function (c) { tr.appendChild(c instanceof Node ? c : el("td", c)); });
      out.appendChild(tr);
    });
    body.replaceChildren(out);
  }
  function statusCell(status, id, cls) {
    var td = el("td", status, "status " + (cls || status.split(" ")[0]));
    if (id) td.setAttribute("data-status-of", id);
    return td;
  }
  // The operator's stop/start/restart of a broker (logged in only; the CSRF token goes along).
  var operator = document.querySelector("#brokers th:last-child").textContent === "operator";
  var csrf = document.querySelector('meta[name="csrf-token"]').content;
  function verbCell(b) {
    var td = el("td", null, "verbs");
    var known = ["absent", "unknown"].indexOf(b.status) < 0;
    var verbs = b.status === "stopped-by-operator" ? ["start"] : ["stop", "restart"];
    if (known) verbs.forEach(function (verb) {
      var button = el("button", verb);
      button.type = "button";
      button.setAttribute("data-verb", verb);
      button.addEventListener("click", function () { brokerVerb(verb, b.id, button); });
      td.appendChild(button);
    });
    return td;
  }
  function brokerVerb(verb, id, button) {
    var note = { stop: "Stop broker " + id + "? It stays stopped (data and config kept) until started.",
      restart: "Restart broker " + id + " now?", start: "Start broker " + id + "?" }[verb];
    if (!window.confirm(note)) return;
    var line = document.getElementById("broker-verb");
    button.disabled = true;
    line.textContent = verb + " " + id + " ...";
    fetch("api/" + verb, { method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRF-Token": csrf },
      body: JSON.stringify({ broker_id: id })
    }).then(function (r) { return r.json().then(function (body) {
      line.textContent = r.ok ? verb + " " + id + ": " + body.broker.status + (body.broker.pid ? ", pid " + body.broker.pid : "")
        : verb + " " + id + " refused: " + body.error;
    }); }).catch(function () { line.textContent = verb + " " + id + ": no answer"; })
      .finally(function () { button.disabled = false; });
  }
  function renderTables(s) {
    fill("brokers", s.brokers, function (b) {
      var tr = [el("td", b.id + (b.in_plant ? "" : " (not in plant)")), b.kind, b.address,
        statusCell(b.status, b.id), el("td", uptime(b.started_at), "uptime"),
        b.restarts === null ? "-" : b.restarts, b.pid || "-",
        b.topics_present + "/" + b.topics_wanted + (b.topics_extra ? " +" + b.topics_extra : "")];
      tr[5] = el("td", tr[5]);
      tr[0].setAttribute("data-broker", b.id);
      tr[4].setAttribute("data-started", b.started_at || "");
      if (b.last_error) tr[3].title = b.last_error;
      if (operator) tr.push(verbCell(b));
      return tr;
    });
    fill("machines", s.machines, function (m) {
      var cls = { answered: "running", "not asked": "absent" }[m.agent_status] || "unknown";
      return [m.host, m.agent || "-", statusCell(m.agent_status, null, cls), m.brokers.join(", ")];
    });
    fill("bridges", s.bridges, function (b) {
      return [b.address + (b.asserted ? "" : " (derived)"), b.mechanism || "-",
        b.routes.map(function (r) { return r.topic + " (" + r.direction + ")"; }).join(", "),
        statusCell(b.status, b.address), b.forwarded === null ? "-" : b.forwarded,
        (b.retried === null ? "-" : b.retried) + (b.refused ? " (" + b.refused + " refused)" : ""), b.restarts === null ? "-" : b.restarts];
    });
    fill("topics", s.topics, function (t) {
      var settings = Object.keys(t.settings).map(function (k) { return k + "=" + t.settings[k]; }).join(" ");
      var rate = el("td", null, "rate");
      rate.setAttribute("data-broker", t.broker_id);
      rate.setAttribute("data-topic", t.name);
      return [t.broker_id, t.name, settings, statusCell(t.present ? "yes" : "no", null, t.present ? "running" : "absent"), rate];
    });
    renderRates();
    document.getElementById("topics-note").textContent =
      s.topics_total > s.topics.length ? "(first " + s.topics.length + " of " + s.topics_total + "; all of them through SPARQL)" : "";
  }
  function renderSummary(s) {
    var banner = document.getElementById("banner");
    banner.hidden = !s.error;
    banner.textContent = s.error || "";
    var v = s.validation;
    document.getElementById("validation-summary").textContent = v.conforms === null ? "not validated" :
      (v.conforms ? "valid" : "invalid") + " (" + v.violations + " violations, " + v.warnings + " warnings)";
    var p = document.getElementById("plan-summary");
    p.replaceChildren();
    var a = el("a", s.plan ? s.plan.line : "no plan");
    a.href = "plan";
    p.appendChild(a);
    var ap = s.apply;
    document.getElementById("apply-summary").textContent = ap.state === "idle" ? "" :
      "apply " + ap.state + (ap.summary.length ? ": " + ap.summary[0] : "");
    document.getElementById("updated").textContent = "version " + s.version + (s.observed_at ?
      ", agents asked " + new Date(s.observed_at * 1000).toLocaleTimeString() : "");
  }
  var COLORS = { running: "#2e7d32", starting: "#f9a825", connecting: "#f9a825", crashed: "#c62828",
    failed: "#c62828", absent: "#9e9e9e", stopped: "#9e9e9e", unknown: "#6a1b9a", resource: "#1565c0" };
  function renderGraph(s) {
    if (typeof cytoscape === "undefined") return;
    var g = s.graph;
    var key = g.nodes.map(function (n) { return n.id; }).join("|") + "#" + g.edges.map(function (e) { return e.id; }).join("|");
    var elements = g.nodes.map(function (n) {
      return { group: "nodes", data: { id: n.id, label: n.label, type: n.type, color: COLORS[n.status] || "#9e9e9e", status: n.status } };
    }).concat(g.edges.map(function (e) {
      return { group: "edges", data: { id: e.id, source: e.source, target: e.target, type: e.type,
        label: e.label || "", color: e.type === "bridge" ? (COLORS[e.status] || "#9e9e9e") : "#b0bec5" } };
    }));
    if (cy && key === graphKey) {
      elements.forEach(function (x) { cy.getElementById(x.data.id).data(x.data); });
      return;
    }
    graphKey = key;
    if (cy) cy.destroy();
    cy = cytoscape({
      container: document.getElementById("graph"), elements: elements, wheelSensitivity: 0.3,
      layout: { name: "breadthfirst", directed: true, spacingFactor: 1.1,
        roots: g.nodes.filter(function (n) { return n.type === "resource"; }).map(function (n) { return n.id; }) },
      style: [
        { selector: "node", style: { "background-color": "data(color)", label: "data(label)", "font-size": 10,
          "text-wrap": "wrap", "text-valign": "bottom", "text-margin-y": 4, width: 18, height: 18 } },
        { selector: "node[type = 'broker']", style: { shape: "round-rectangle", width: 34, height: 26 } },
        { selector: "edge", style: { width: 1.5, "line-color": "data(color)", "target-arrow-color": "data(color)",
          "target-arrow-shape": "triangle", "curve-style": "bezier", label: "data(label)", "font-size": 8,
          "text-background-color": "#fff", "text-background-opacity": 1, "text-background-padding": 2 } },
        { selector: "edge[type = 'bridge']", style: { width: 3, "line-style": "dashed" } }
      ]
    });
    window.plantGraph = cy;
  }
  function render(s) {
    current = s;
    renderSummary(s);
    renderTables(s);
    renderGraph(s);
    document.body.setAttribute("data-version", s.version);
  }
  // Live message rates (/api/rates): the last second's count and a sparkline of the last minute.
  var rates = {};
  var SVG = "http://www.w3.org/2000/svg";
  function sparkline(perS) {
    var w = 120, h = 18, max = Math.max.apply(null, perS.concat([1]));
    var step = perS.length > 1 ? w / (perS.length - 1) : w;
    var svg = document.createElementNS(SVG, "svg");
    svg.setAttribute("class", "sparkline");
    svg.setAttribute("width", w);
    svg.setAttribute("height", h);
    svg.setAttribute("viewBox", "0 0 " + w + " " + h);
    var line = document.createElementNS(SVG, "polyline");
    line.setAttribute("points", perS.map(function (v, i) {
      return (i * step).toFixed(1) + "," + (h - 1 - (v / max) * (h - 2)).toFixed(1);
    }).join(" "));
    svg.appendChild(line);
    return svg;
  }
  function renderRates() {
    document.querySelectorAll("#topics td.rate").forEach(function (td) {
      var r = rates[JSON.stringify([td.getAttribute("data-broker"), td.getAttribute("data-topic")])];
      if (!r) { td.replaceChildren(el("span", "-", "muted")); td.removeAttribute("data-rate"); td.title = ""; return; }
      var last = r.per_s.length ? r.per_s[r.per_s.length - 1] : 0;
      td.setAttribute("data-rate", last);
      td.title = r.error ? "not watched: " + r.error :
        last + " msg/s in the last second, " + r.total + " since watched (" + r.per_s.length + " s shown)";
      td.replaceChildren(el("span", last + "/s", "rate-value" + (r.watching ? "" : " muted")), sparkline(r.per_s));
    });
  }
  function pollRates() {
    fetch("api/rates", { credentials: "same-origin" }).then(function (r) {
      if (r.status === 200) return r.json().then(function (doc) {
        var next = {};
        doc.topics.forEach(function (t) { next[JSON.stringify([t.broker, t.topic])] = t; });
        rates = next;
        renderRates();
      });
    }).catch(function () { /* the server restarts: try again next time */ });
  }
  function poll() {
    pollRates();
    var headers = etag ? { "If-None-Match": etag } : {};
    fetch("api/status", { headers: headers, credentials: "same-origin" }).then(function (r) {
      if (r.status === 200) { etag = r.headers.get("ETag"); return r.json().then(render); }
    }).catch(function () { /* the server restarts: try again next time */ })
      .finally(function () { setTimeout(poll, POLL_MS); });
  }
  setInterval(function () {
    document.querySelectorAll("td.uptime").forEach(function (td) {
      var started = parseFloat(td.getAttribute("data-started"));
      td.textContent = uptime(isNaN(started) ? null : started);
    });
  }, 1000);
  render(current);
  pollRates();
  etag = '"' + current.version + '"';
  setTimeout(poll, POLL_MS);
})();
