// thermocomp dashboard: one page, no build step. Talks to /api/v1 (REST) and /api/v1/ws.
// Every value from the daemon reaches the page through textContent, never as HTML.
"use strict";

(() => {
  const API = "/api/v1";
  const MAX_POINTS = 20000; // per plot; older points are dropped from the live view
  const TEMPERATURE_SERIES = 6; // model nodes shown (spread along the link), plus IR regions
  const $ = (id) => document.getElementById(id);

  const state = {
    token: localStorage.getItem("thermocomp-token") || "",
    runId: null,
    daemonState: "idle",
    lastStep: -1,
    durationS: null,
    socket: null,
    reconnectDelay: 500,
    lost: 0,
    steps: 0,
    dirty: false,
  };

  // --- REST ------------------------------------------------------------------------------

  async function api(method, path, body) {
    const headers = { Accept: "application/json" };
    if (state.token) headers.Authorization = `Bearer ${state.token}`;
    if (body !== undefined) headers["Content-Type"] = "application/json";
    const response = await fetch(API + path, {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    const text = await response.text();
    let data = null;
    try { data = text ? JSON.parse(text) : null; } catch { data = { message: text }; }
    if (!response.ok) {
      const error = new Error((data && data.message) || `${response.status}`);
      error.status = response.status;
      error.body = data;
      throw error;
    }
    return data;
  }

  function say(text, isError = false) {
    const message = $("message");
    message.textContent = text;
    message.className = isError ? "error" : "";
  }

  function fail(error) {
    const hint = error.status === 401 || error.status === 403 ? " (enter a control token)" : "";
    say(`${error.status || ""} ${error.message}${hint}`, true);
  }

  // --- plots -----------------------------------------------------------------------------

  function makePlot(elementId, seriesNames, colours) {
    const element = $(elementId);
    const data = [[], ...seriesNames.map(() => [])];
    const options = {
      width: Math.max(element.clientWidth, 300),
      height: 180,
      scales: { x: { time: false } },
      axes: [{ label: "run time (s)" }, {}],
      legend: { live: false },
      series: [{}, ...seriesNames.map((name, i) => ({
        label: name, stroke: colours[i % colours.length], width: 1.5, spanGaps: true,
      }))],
    };
    return { plot: new uPlot(options, data, element), data, names: seriesNames, element };
  }

  const COLOURS = ["#1f6feb", "#c62828", "#2e7d32", "#8e24aa", "#ef6c00", "#00838f", "#6d4c41"];
  const plots = {
    predicted: makePlot("plot-predicted", ["x", "y", "z"], COLOURS),
    offset: makePlot("plot-offset", ["x", "y", "z"], COLOURS),
    residual: makePlot("plot-residual", ["residual"], ["#c62828"]),
    temperature: null, // built on the first step, when the node names are known
  };

  function num(value) {
    return value === null || value === undefined || value === "" ? null : Number(value);
  }

  function scaled(value, factor) {
    const n = num(value);
    return n === null ? null : n * factor;
  }

  function temperatureSeries(step) {
    const names = [];
    let model = {};
    try { model = step.model_temperatures_json ? JSON.parse(step.model_temperatures_json) : {}; }
    catch { model = {}; }
    const nodes = Object.keys(model);
    const every = Math.max(1, Math.ceil(nodes.length / TEMPERATURE_SERIES));
    nodes.forEach((node, i) => { if (i % every === 0) names.push(`node ${node}`); });
    let ir = {};
    try { ir = step.ir_json ? JSON.parse(step.ir_json) : {}; } catch { ir = {}; }
    Object.keys(ir).forEach((region) => names.push(`IR ${region}`));
    return names;
  }

  function temperatureValues(step, names) {
    let model = {};
    let ir = {};
    try { model = step.model_temperatures_json ? JSON.parse(step.model_temperatures_json) : {}; }
    catch { model = {}; }
    try { ir = step.ir_json ? JSON.parse(step.ir_json) : {}; } catch { ir = {}; }
    return names.map((name) => {
      if (name.startsWith("node ")) return num(model[name.slice(5)]);
      const region = ir[name.slice(3)];
      return region ? num(region.mean_c) : null;
    });
  }

  function resetPlots() {
    for (const key of ["predicted", "offset", "residual"]) {
      plots[key].data.forEach((column) => { column.length = 0; });
    }
    if (plots.temperature) {
      plots.temperature.plot.destroy();
      plots.temperature = null;
    }
    state.steps = 0;
    state.dirty = true;
  }

  function push(plotState, x, values) {
    const { data } = plotState;
    data[0].push(x);
    values.forEach((v, i) => data[i + 1].push(v));
    if (data[0].length > MAX_POINTS) data.forEach((column) => column.shift());
  }

  function addStep(step) {
    if (step.run_id !== state.runId) {
      state.runId = step.run_id;
      resetPlots();
    }
    const t = num(step.scheduled_s);
    push(plots.predicted, t, [num(step.predicted_x_um), num(step.predicted_y_um),
      num(step.predicted_z_um)]);
    push(plots.offset, t, [scaled(step.offset_x_mm, 1000), scaled(step.offset_y_mm, 1000),
      scaled(step.offset_z_mm, 1000)]);
    push(plots.residual, t, [num(step.residual_um)]);
    if (!plots.temperature) {
      const names = temperatureSeries(step);
      if (names.length) plots.temperature = makePlot("plot-temperature", names, COLOURS);
    }
    if (plots.temperature) {
      push(plots.temperature, t, temperatureValues(step, plots.temperature.names));
    }
    state.lastStep = step.step;
    state.steps += 1;
    state.dirty = true;
    if (state.durationS && t !== null) showProgress(Math.min(100, (100 * t) / state.durationS));
  }

  function redraw() {
    if (state.dirty) {
      state.dirty = false;
      for (const plotState of Object.values(plots)) {
        if (plotState) plotState.plot.setData(plotState.data);
      }
      $("run-step").textContent = state.lastStep >= 0 ? String(state.lastStep) : "–";
    }
    requestAnimationFrame(redraw);
  }

  window.addEventListener("resize", () => {
    for (const plotState of Object.values(plots)) {
      if (plotState) {
        plotState.plot.setSize({ width: Math.max(plotState.element.clientWidth, 300),
          height: 180 });
      }
    }
  });

  // --- state, errors, history ------------------------------------------------------------

  function showState(snapshot) {
    if (!snapshot) return;
    const daemonState = snapshot.state || "idle";
    state.daemonState = daemonState;
    const badge = $("daemon-state");
    badge.textContent = daemonState;
    badge.className = `badge ${daemonState}`;
    const run = snapshot.run;
    if (run) {
      $("run-id").textContent = `${run.id} (${run.state})`;
      if (state.runId !== run.id) {
        state.runId = run.id;
        resetPlots();
        backfill(run.id);
      }
      state.durationS = run.parameters ? Number(run.parameters.duration_s) : null;
      showProgress(Number(run.progress_percent || 0));
    }
    const lateness = snapshot.timing && snapshot.timing.lateness_s;
    if (lateness && lateness.p99 !== null && lateness.p99 !== undefined) {
      $("lateness-p99").textContent = `${(lateness.p99 * 1000).toFixed(2)} ms`;
    }
    if (Array.isArray(snapshot.errors)) showErrors(snapshot.errors);
    const active = !["idle", "finished", "aborted", "interrupted"].includes(daemonState);
    $("btn-start").disabled = active;
    $("btn-pause").disabled = daemonState !== "running";
    $("btn-resume").disabled = !["paused", "fault"].includes(daemonState);
    $("btn-stop").disabled = !active;
  }

  function showProgress(percent) {
    $("run-progress").value = percent;
    $("run-progress-text").textContent = `${percent.toFixed(1)} %`;
  }

  async function backfill(runId) {
    try {
      // JSON pages are capped (5,000 steps): follow next_from up to the plot's capacity
      const steps = [];
      let from = 0;
      while (from !== null && steps.length < MAX_POINTS) {
        const page = await api("GET", `/runs/${runId}/steps?format=json&from=${from}&limit=5000`);
        if (state.runId !== runId) return;
        steps.push(...page.steps);
        from = page.next_from;
      }
      const seen = state.lastStep;
      resetPlots();
      state.runId = runId;
      for (const step of steps) addStep(step);
      if (seen > state.lastStep) state.lastStep = seen;
    } catch (error) {
      if (error.status !== 404) fail(error);
    }
  }

  function showErrors(errors) {
    const list = $("error-list");
    list.replaceChildren();
    for (const entry of errors.slice(-50).reverse()) addError(entry, list, false);
  }

  function addError(entry, list = $("error-list"), atTop = true) {
    const item = document.createElement("li");
    const meta = document.createElement("span");
    meta.className = "meta";
    const when = entry.time ? new Date(entry.time * 1000).toLocaleTimeString() : "";
    meta.textContent = `${when} ${entry.device || ""} ${entry.kind || ""}: `;
    item.append(meta, document.createTextNode(entry.message || ""));
    if (atTop) list.prepend(item); else list.append(item);
    while (list.children.length > 50) list.lastChild.remove();
  }

  async function refreshHistory() {
    try {
      const page = await api("GET", "/runs?limit=20");
      const body = $("run-history");
      body.replaceChildren();
      for (const run of page.runs) body.append(historyRow(run));
    } catch (error) {
      if (error.status !== 503) fail(error);
    }
  }

  function historyRow(run) {
    const row = document.createElement("tr");
    const summary = run.summary || {};
    const cells = [
      String(run.id),
      run.state,
      new Date(run.started_at * 1000).toLocaleString(),
      String(run.steps_recorded),
      summary.residual_max_um === undefined || summary.residual_max_um === null
        ? "–" : Number(summary.residual_max_um).toFixed(2),
      summary.reduction_percent === undefined || summary.reduction_percent === null
        ? "–" : Number(summary.reduction_percent).toFixed(1),
    ];
    for (const text of cells) {
      const cell = document.createElement("td");
      cell.textContent = text;
      row.append(cell);
    }
    const links = document.createElement("td");
    for (const [label, href] of [["CSV", run.links.steps_csv],
      ["Parquet", run.links.steps_parquet], ["report", run.links.report]]) {
      if (!href) continue; // no Parquet link when the server lacks the optional pyarrow
      const link = document.createElement("a");
      link.textContent = label;
      link.href = href;
      link.addEventListener("click", (event) => { event.preventDefault(); download(href, run.id); });
      links.append(link);
    }
    row.append(links);
    return row;
  }

  // Links carry the token in a header, so they are fetched and handed over as a blob.
  async function download(href, runId) {
    const headers = state.token ? { Authorization: `Bearer ${state.token}` } : {};
    const response = await fetch(href, { headers });
    if (!response.ok) {
      let message = `${response.status}`;
      try { message = (await response.json()).message; } catch { /* not JSON */ }
      say(`run ${runId}: ${message}`, true);
      return;
    }
    const blob = await response.blob();
    const url = URL.createObjectURL(blob);
    if (blob.type.startsWith("text/html")) {
      window.open(url, "_blank");
    } else {
      const anchor = document.createElement("a");
      anchor.href = url;
      anchor.download = href.includes("parquet") ? `run-${runId}-steps.parquet`
        : `run-${runId}-steps.csv`;
      anchor.click();
    }
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  }

  async function refreshState() {
    try {
      showState(await api("GET", "/state"));
    } catch (error) {
      if (error.status === 401 || error.status === 403) say("enter a read token", true);
    }
  }

  // --- camera frame -----------------------------------------------------------------------

  function showFrame(frame) {
    const image = new Image();
    image.onload = () => {
      const canvas = $("frame-canvas");
      canvas.width = frame.width;
      canvas.height = frame.height;
      const context = canvas.getContext("2d");
      context.drawImage(image, 0, 0);
      const x = num(frame.centroid_x_px);
      const y = num(frame.centroid_y_px);
      if (x !== null && y !== null) {
        // a thumbnail pixel is a scale x scale block; frame pixel centres are at integers
        const cx = (x + 0.5) / frame.scale;
        const cy = (y + 0.5) / frame.scale;
        // a cross with a gap in the middle, so the spot itself stays visible
        context.strokeStyle = "#ff3b30";
        context.lineWidth = 1;
        context.beginPath();
        for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) {
          context.moveTo(cx + 4 * dx, cy + 4 * dy);
          context.lineTo(cx + 12 * dx, cy + 12 * dy);
        }
        context.stroke();
      }
      const where = x === null ? "no centroid" : `centroid (${x.toFixed(2)}, ${y.toFixed(2)}) px`;
      $("frame-caption").textContent = `run ${frame.run_id} step ${frame.step}: ${where}`;
    };
    image.src = `data:image/png;base64,${frame.png_base64}`;
  }

  // --- WebSocket --------------------------------------------------------------------------

  function base64url(text) {
    const bytes = new TextEncoder().encode(text);
    let binary = "";
    for (const byte of bytes) binary += String.fromCharCode(byte);
    return btoa(binary).replace(/\+/g, "-").replace(/\//g, "_").replace(/=+$/, "");
  }

  function connect() {
    if (state.socket) state.socket.close();
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const query = new URLSearchParams({ topics: "steps,state,errors,frames" });
    // the token travels as a subprotocol (base64url), never in the URL that servers log
    const protocols = ["thermocomp.v1"];
    if (state.token) protocols.push(`bearer.${base64url(state.token)}`);
    const socket = new WebSocket(`${scheme}://${location.host}${API}/ws?${query}`, protocols);
    state.socket = socket;
    const badge = $("stream-state");
    socket.onopen = () => {
      badge.textContent = "open";
      badge.className = "badge open";
      state.reconnectDelay = 500;
    };
    socket.onclose = () => {
      if (state.socket !== socket) return;
      badge.textContent = "closed";
      badge.className = "badge closed";
      setTimeout(connect, state.reconnectDelay);
      state.reconnectDelay = Math.min(state.reconnectDelay * 2, 10000);
    };
    socket.onmessage = (event) => {
      const message = JSON.parse(event.data);
      switch (message.type) {
        case "hello": showState(message.data.state); break;
        case "step": addStep(message.data); break;
        case "state": refreshState(); refreshHistory(); break;
        case "error": addError(message.data); break;
        case "frame": showFrame(message.data); break;
        case "lost": {
          state.lost += message.data.count;
          const lost = $("stream-lost");
          lost.hidden = false;
          lost.textContent = `${state.lost} messages lost (slow connection)`;
          break;
        }
        default: break;
      }
    };
  }

  // --- controls ---------------------------------------------------------------------------

  function control(path) {
    return async () => {
      try {
        await api("POST", path());
        say("done");
        await refreshState();
      } catch (error) {
        fail(error);
      }
    };
  }

  $("start-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const body = {};
    for (const [name, value] of new FormData(event.target)) {
      if (value === "") continue;
      const input = event.target.elements[name];
      body[name] = input.type === "number" ? Number(value) : value;
    }
    try {
      const run = await api("POST", "/runs", body);
      say(`run ${run.id} started`);
      state.runId = run.id;
      resetPlots();
      await refreshState();
      await refreshHistory();
    } catch (error) {
      const fields = error.body && Array.isArray(error.body.details)
        ? error.body.details.map((d) => `${d.field}: ${d.message}`).join("; ") : "";
      if (fields) say(`${error.status} ${fields}`, true); else fail(error);
    }
  });

  $("btn-pause").addEventListener("click", control(() => `/runs/${state.runId}/pause`));
  $("btn-resume").addEventListener("click", control(() => `/runs/${state.runId}/resume`));
  $("btn-stop").addEventListener("click", control(() => `/runs/${state.runId}/stop`));
  $("btn-hold").addEventListener("click", control(() => "/robot/stop"));

  $("token").value = state.token;
  $("token-form").addEventListener("submit", (event) => {
    event.preventDefault();
    state.token = $("token").value.trim();
    localStorage.setItem("thermocomp-token", state.token);
    say(state.token ? "token set" : "token cleared");
    connect();
    refreshState();
    refreshHistory();
  });

  async function loadNetworks() {
    try {
      const list = await api("GET", "/networks");
      const select = $("network-select");
      for (const network of list.networks) {
        const option = document.createElement("option");
        option.value = network.name;
        option.textContent = network.name;
        option.title = network.description;
        select.append(option);
      }
    } catch { /* the list is a convenience; the config's network is the default */ }
  }

  // exposed for the browser test and for curious users in the console
  window.thermocomp = { state, plots };

  // the stream carries steps and state changes; a slow poll keeps timing and history fresh
  setInterval(() => {
    if (!["idle", "finished", "aborted", "interrupted"].includes(state.daemonState)) {
      refreshState();
      refreshHistory();
    }
  }, 3000);

  requestAnimationFrame(redraw);
  connect();
  refreshState();
  refreshHistory();
  loadNetworks();
})();
