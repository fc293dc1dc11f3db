// The SPARQL page: runs the query against /sparql (SPARQL JSON, or Turtle for CONSTRUCT/DESCRIBE)
// and shows the answer as a table.
(function () {
  "use strict";
  var form = document.getElementById("query-form");
  var textarea = document.getElementById("query");
  var examples = JSON.parse(document.getElementById("example-queries").textContent);
  var errorBox = document.getElementById("query-error");
  var table = document.getElementById("results");
  var graphOut = document.getElementById("graph-results");
  var info = document.getElementById("query-info");

  document.getElementById("examples").addEventListener("change", function (ev) {
    textarea.value = examples[parseInt(ev.target.value, 10)];
  });
  function cell(term) {
    if (!term) return "";
    if (term.type === "literal" && term["xml:lang"]) return term.value + "@" + term["xml:lang"];
    if (term.type === "bnode") return "_:" + term.value;
    return term.value;
  }
  function showTable(data) {
    var head = document.createElement("tr");
    var vars = data.head.vars || ["boolean"];
    vars.forEach(function (v) { var th = document.createElement("th"); th.textContent = v; head.appendChild(th); });
    table.tHead.replaceChildren(head);
    var rows = data.results ? data.results.bindings : [{ boolean: { value: String(data.boolean) } }];
    var body = document.createDocumentFragment();
    rows.forEach(function (b) {
      var tr = document.createElement("tr");
      vars.forEach(function (v) { var td = document.createElement("td"); td.textContent = cell(b[v]); tr.appendChild(td); });
      body.appendChild(tr);
    });
    table.tBodies[0].replaceChildren(body);
    info.textContent = rows.length + " row" + (rows.length === 1 ? "" : "s");
  }
  form.addEventListener("submit", function (ev) {
    ev.preventDefault();
    errorBox.hidden = true; graphOut.hidden = true;
    table.tHead.replaceChildren(); table.tBodies[0].replaceChildren();
    info.textContent = "running…";
    var started = performance.now();
    fetch(form.getAttribute("data-endpoint"), {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/x-www-form-urlencoded",
        "Accept": "application/sparql-results+json, text/turtle;q=0.9" },
      body: new URLSearchParams({ query: textarea.value })
    }).then(function (r) {
      var type = r.headers.get("Content-Type") || "";
      if (!r.ok) return r.text().then(function (t) { throw new Error(r.status + ": " + t); });
      if (type.indexOf("json") >= 0) return r.json().then(showTable);
      return r.text().then(function (t) { graphOut.textContent = t; graphOut.hidden = false; info.textContent = "graph"; });
    }).then(function () {
      info.textContent += " in " + Math.round(performance.now() - started) + " ms";
    }).catch(function (e) {
      errorBox.textContent = e.message; errorBox.hidden = false; info.textContent = "";
    });
  });
})();
