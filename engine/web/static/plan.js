// The plan page: Apply (after confirmation) posts the plan's fingerprint with the CSRF token,
// then follows the apply in /api/status until it ends.
(function () {
  "use strict";
  var csrf = document.querySelector('meta[name="csrf-token"]').content;
  var section = document.getElementById("apply-status");
  var shownPlan = section.getAttribute("data-fingerprint");
  var form = document.getElementById("apply-form");
  var etag = null;

  function show(s) {
    var ap = s.apply;
    document.getElementById("apply-state").textContent = ap.state;
    document.getElementById("apply-log").textContent = (ap.summary.length ? ap.summary : ap.progress).join("\n");
    var planNow = s.plan ? s.plan.fingerprint : "";
    document.getElementById("plan-changed").hidden = (planNow || "") === shownPlan || ap.state === "running";
    if (form) form.querySelector("button").disabled = ap.state === "running" || (planNow || "") !== shownPlan;
  }
  function poll() {
    fetch("api/status", { headers: etag ? { "If-None-Match": etag } : {}, credentials: "same-origin" })
      .then(function (r) { if (r.status === 200) { etag = r.headers.get("ETag"); return r.json().then(show); } })
      .catch(function () {})
      .finally(function () { setTimeout(poll, 1000); });
  }
  if (form) {
    form.addEventListener("submit", function (ev) {
      ev.preventDefault();
      if (!window.confirm("Apply this plan to the running plant? Brokers may be started, replaced or stopped.")) return;
      fetch(form.getAttribute("data-api"), {
        method: "POST", credentials: "same-origin",
        headers: { "Content-Type": "application/json", "X-CSRF-Token": csrf },
        body: JSON.stringify({ fingerprint: form.getAttribute("data-fingerprint") })
      }).then(function (r) { return r.json().then(function (body) {
        document.getElementById("apply-state").textContent = r.ok ? "running" : "refused: " + body.error;
      }); });
    });
  }
  poll();
})();
