// A station's page: live state (ready to load / unload), the Loaded / Unloaded buttons, start a
// job, the jobs passing here. Polls /api/stations/<name> every 0.5 s.
"use strict";
(function () {
  const name = document.getElementById("station").dataset.station;
  const base = "/api/stations/" + encodeURIComponent(name);
  const message = document.getElementById("message");
  const buttons = {loaded: document.getElementById("loaded"), unloaded: document.getElementById("unloaded")};
  let last = null;

  function say(text, bad) {
    message.textContent = text;
    message.className = bad ? "error" : "ok";
  }

  function render(view, status) {
    if (status !== 200) { say(view.error || ("HTTP " + status), true); return; }
    last = view;
    HMI.banner([view.planner]);
    const ready = document.getElementById("ready");
    ready.textContent = view.ready || (view.planner.ok ? "no vehicle waits here" : "unknown: the planner does not answer");
    ready.dataset.ready = view.ready || "";
    const waiting = view.waiting.map(w => w.vehicle + " (" + w.task + ")").join(", ");
    const coming = view.approaching.map(a => a.vehicle + " on its way (" + a.task + ": " + a.step + ")").join(", ");
    document.getElementById("approaching").textContent = [waiting && ("waiting: " + waiting), coming].filter(Boolean).join("; ");
    buttons.loaded.disabled = !view.loadReady;
    buttons.unloaded.disabled = !view.unloadReady;
    HMI.fill(document.querySelector("#jobs tbody"), tbody => {
      for (const job of view.jobs) {
        for (const t of job.tasks) {
          HMI.row(tbody, [job.job, job.state, t.id, t.state, t.vehicle, t.step],
                  {"data-job": job.job, "data-job-state": job.state, "data-task": t.id});
        }
      }
    });
  }

  for (const [button, el] of Object.entries(buttons)) {
    el.addEventListener("click", async () => {
      el.disabled = true;
      const {status, body} = await HMI.post(base + "/" + button);
      if (status === 201) say(el.textContent + ": sent " + body.fired.map(e => e.event + " (#" + e.number + ")").join(", "), false);
      else say(el.textContent + " refused: " + (body.error || status), true);
    });
  }

  document.getElementById("start").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const task = document.getElementById("job-task").value;
    const {status, body} = await HMI.post(base + "/jobs", {task: task});
    if (status === 201) {
      say("job " + body.job + " started: " + body.tasks.join(", "), false);
      message.dataset.job = body.job;
    } else {
      say("not started: " + (body.error || status), true);
    }
  });

  HMI.poll(base, render);
  window.hmiStation = () => last;
})();
