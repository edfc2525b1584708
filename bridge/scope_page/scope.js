// The live scope's page (bridge/scope.py): polls GET /data?after=SEQ, keeps the samples of
// the chosen window, draws them with uPlot. Read-only: only GET requests are made.
"use strict";
(function () {
  const POLL_MS = 200;
  const scope = { samples: 0, lastT: null, polls: 0, paused: false, dropped: 0, pushed: 0 };
  window.scope = scope;
  let meta = null, after = 0, windowS = 10;
  const cols = { t: [], e: [], beta: [], lam: [], wm: [], wl: [], tq: [] };
  let lastX = null, lastTx = null;
  const plots = [];
  scope.cols = cols;

  function um(v) { return v === null ? null : v * 1e6; }
  function unitScale() { return meta.load_unit === "m" ? ["µm", 1e6] : ["µrad", 1e6]; }

  function makePlots() {
    const [u] = unitScale();
    const el = document.getElementById("plots");
    const width = Math.max(300, (el.clientWidth - 8) / 2);
    const spec = [
      { title: `following error x_ref − x_l, ${u}`, series: [["e", "e", "#c33"]] },
      { title: "β, rad/s (Fig. 5) and λ (eq. 15)", series: [["β", "beta", "#36c"], ["λ", "lam", "#393"]] },
      { title: "speed, motor rad/s (load × k_r)", series: [["motor", "wm", "#c60"], ["load × k_r", "wl", "#639"]] },
      { title: "motor torque, N·m (6077h)", series: [["torque", "tq", "#066"]] },
    ];
    for (const s of spec) {
      const opts = {
        title: s.title, width: width, height: 260,
        scales: { x: { time: false } },
        axes: [{ label: "t, s" }, {}],
        series: [{ label: "t, s" }].concat(s.series.map(([label, , stroke]) => ({ label, stroke, width: 1.5 }))),
      };
      const keys = s.series.map(([, k]) => k);
      const plot = new uPlot(opts, [[]].concat(keys.map(() => [])), el);
      plots.push({ plot, keys });
    }
  }

  function trim() {
    if (!cols.t.length) return;
    const from = cols.t[cols.t.length - 1] - windowS;
    let i = 0;
    while (i < cols.t.length && cols.t[i] < from) i++;
    if (i) for (const k in cols) cols[k].splice(0, i);
  }

  function redraw() {
    for (const { plot, keys } of plots) plot.setData([cols.t].concat(keys.map((k) => cols[k])));
  }

  function add(d) {
    const s = d.samples, n = s.seq.length, kr = meta.transmission_ratio;
    const [, f] = unitScale();
    for (let i = 0; i < n; i++) {
      const t = s.t_s[i], x = s.load_position[i];
      if (lastTx !== null && t < lastTx) {  // a new run (hil demo --scope): start afresh
        for (const k in cols) cols[k].length = 0;
        lastX = null;
      }
      let wl = null;
      if (lastX !== null && x !== null && t > lastTx) wl = (x - lastX) / (t - lastTx) * kr;
      lastX = x; lastTx = t;
      cols.t.push(t);
      cols.e.push(s.following_error[i] === null ? null : s.following_error[i] * f);
      cols.beta.push(s.beta_rad_s[i]);
      cols.lam.push(s.lambda[i]);
      cols.wm.push(s.motor_speed_rad_s[i]);
      cols.wl.push(wl);
      cols.tq.push(s.torque_nm[i]);
    }
    scope.samples += n;
    if (n) scope.lastT = s.t_s[n - 1];
    scope.dropped = d.dropped; scope.pushed = d.pushed;
    after = d.last_seq;
    if (d.state) {
      const st = document.getElementById("state");
      st.textContent = d.state; st.className = d.state;
      document.getElementById("stop").textContent =
        d.stop === "NONE" ? "none" : `${d.stop}: ${d.stop_message}`;
    }
    document.getElementById("counts").textContent =
      `${scope.samples} samples shown of ${d.pushed} cycles, ${d.dropped} dropped` +
      (scope.lastT === null ? "" : `, t ${scope.lastT.toFixed(3)} s`) + (d.running ? "" : " (run ended)");
  }

  async function poll() {
    try {
      const r = await fetch(`data?after=${after}`, { cache: "no-store" });
      if (r.ok) {
        const d = await r.json();
        scope.polls++;
        if (!scope.paused) { add(d); trim(); redraw(); } else { after = d.last_seq; }
        if (!d.running) return;  // the run ended: the last samples are shown
      }
    } catch (e) {
      // the run ended and the server with it: keep what is shown
      return;
    }
    setTimeout(poll, POLL_MS);
  }

  // resolves once the page has shown more than n samples (a test waits for a state)
  scope.waitForSamples = function (n) {
    return new Promise((resolve) => {
      (function check() { if (scope.samples > n) resolve(scope.samples); else setTimeout(check, 50); })();
    });
  };

  function exportCsv() {
    const [u] = unitScale();
    const head = `t_s,following_error_${u},beta_rad_s,lambda,motor_speed_rad_s,load_speed_x_kr_rad_s,torque_nm`;
    const lines = [head];
    for (let i = 0; i < cols.t.length; i++) {
      lines.push([cols.t[i], cols.e[i], cols.beta[i], cols.lam[i], cols.wm[i], cols.wl[i], cols.tq[i]]
        .map((v) => (v === null ? "" : String(v))).join(","));
    }
    const blob = new Blob([lines.join("\n") + "\n"], { type: "text/csv" });
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = "scope.csv";
    a.click();
    scope.lastExport = lines.length - 1;
  }
  scope.csvRows = () => cols.t.length;

  const asked = new URLSearchParams(location.search).get("window");  // ?window=SECONDS
  if (asked !== null && Number(asked) > 0) {
    windowS = Number(asked);
    const sel = document.getElementById("window");
    if (![...sel.options].some((o) => o.value === asked)) sel.add(new Option(`${asked} s`, asked));
    sel.value = asked;
  }
  document.getElementById("window").addEventListener("change", (ev) => {
    windowS = Number(ev.target.value); trim(); redraw();
  });
  document.getElementById("pause").addEventListener("click", (ev) => {
    scope.paused = !scope.paused;
    ev.target.textContent = scope.paused ? "resume" : "pause";
  });
  document.getElementById("export").addEventListener("click", exportCsv);

  fetch("meta", { cache: "no-store" }).then((r) => r.json()).then((m) => {
    meta = m;
    document.getElementById("uplot").textContent = m.uplot;
    makePlots();
    poll();
  });
})();
