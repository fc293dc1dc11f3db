// The HMI's shared helpers: polling JSON endpoints (no overlap), CSRF-protected POSTs, the banner
// that says which upstream (planner, fleet manager) does not answer. Text only (no innerHTML).
"use strict";
window.HMI = (function () {
  const csrf = document.querySelector('meta[name="csrf-token"]').content;
  const PERIOD_MS = 500;

  function poll(url, onData) {
    async function once() {
      try {
        const reply = await fetch(typeof url === "function" ? url() : url, {credentials: "same-origin"});
        if (reply.status === 401) { window.location = "/login?next=" + encodeURIComponent(window.location.pathname); return; }
        const body = await reply.json();
        onData(body, reply.status);
      } catch (err) {
        banner([{ok: false, error: "the HMI does not answer: " + err}]);
      } finally {
        setTimeout(once, PERIOD_MS);
      }
    }
    once();
  }

  async function post(url, fields) {
    const reply = await fetch(url, {
      method: "POST", credentials: "same-origin",
      headers: {"X-CSRF-Token": csrf, "Content-Type": "application/x-www-form-urlencoded"},
      body: new URLSearchParams(fields || {}),
    });
    let body = {};
    try { body = await reply.json(); } catch (err) { body = {error: "HTTP " + reply.status}; }
    return {status: reply.status, body: body};
  }

  function banner(parts) {
    const el = document.getElementById("upstream");
    const down = parts.filter(p => p && p.ok === false).map(p => p.error);
    el.textContent = down.join(" — ");
    el.hidden = down.length === 0;
  }

  function row(tbody, cells, attrs) {
    const tr = document.createElement("tr");
    for (const [k, v] of Object.entries(attrs || {})) tr.setAttribute(k, v);
    for (const c of cells) {
      const td = document.createElement("td");
      if (c instanceof Node) td.appendChild(c); else td.textContent = c === null || c === undefined ? "" : String(c);
      tr.appendChild(td);
    }
    tbody.appendChild(tr);
    return tr;
  }

  function fill(tbody, build) {
    const fresh = tbody.cloneNode(false);
    build(fresh);
    tbody.replaceWith(fresh);
    return fresh;
  }

  // Keyed update of a table body: a row per key is kept (a button in it stays clickable across
  // polls), its cells' text changed only where it differs, rows put in order, gone ones removed.
  function sync(tbody, items, keyOf, cellsOf, attrsOf, decorate) {
    const rows = new Map([...tbody.children].map(tr => [tr.dataset.key, tr]));
    const keep = new Set();
    items.forEach((item, i) => {
      const key = String(keyOf(item));
      keep.add(key);
      let tr = rows.get(key);
      const cells = cellsOf(item);
      if (!tr) {
        tr = document.createElement("tr");
        tr.dataset.key = key;
        for (let c = 0; c < cells.length; c++) tr.appendChild(document.createElement("td"));
      }
      cells.forEach((text, c) => {
        const value = text === null || text === undefined ? "" : String(text);
        if (tr.children[c].textContent !== value) tr.children[c].textContent = value;
      });
      for (const [k, v] of Object.entries(attrsOf(item))) if (tr.getAttribute(k) !== v) tr.setAttribute(k, v);
      if (decorate) decorate(tr, item);
      if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] || null);
    });
    for (const [key, tr] of rows) if (!keep.has(key)) tr.remove();
  }

  return {poll, post, banner, row, fill, sync, csrf};
})();
