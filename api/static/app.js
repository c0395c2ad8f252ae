// thermocomp dashboard: one page, no build step. Talks to /api/v1 (REST) and /api/v1/ws.
// Every value from the daemon reaches the page through textContent, never as HTML.
"use strict";

(() => {
  const API = "/api/v1";
  const MAX_POINTS = 20000; // per plot; older points are dropped from the live view
  const POLL_MS = 3000; // state, history and device health, besides the stream
  // the daemon's states while a run is under way; anything else is idle or a final word
  const ACTIVE_STATES = ["starting", "running", "paused", "stopping", "fault"];
  const $ = (id) => document.getElementById(id);
  // natural order: node 2 before node 16, region "node-2" before "node-16"
  const naturally = new Intl.Collator(undefined, { numeric: true, sensitivity: "base" }).compare;

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
    tokenRefused: false, // the token was refused for reading: read anonymously meanwhile
    runReason: null,
  };

  // --- REST ------------------------------------------------------------------------------

  function apiError(response, data) {
    // the API's error body: {"status", "kind", "message", "details"}
    const error = new Error((data && data.message) || `${response.status} ${response.statusText}`);
    error.status = response.status;
    error.kind = data && data.kind;
    error.body = data;
    return error;
  }

  async function api(method, path, body) {
    const headers = { Accept: "application/json" };
    // a refused token is still sent with control requests (their answer says it is refused)
    // but not with reads, which the server may allow anonymously: the plots keep going
    const reading = method === "GET";
    if (state.token && !(reading && state.tokenRefused)) {
      headers.Authorization = `Bearer ${state.token}`;
    }
    if (body !== undefined) headers["Content-Type"] = "application/json";
    const response = await fetch(API + path, {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    const text = await response.text();
    let data = null;
    try { data = text ? JSON.parse(text) : null; } catch { data = { message: text }; }
    if (response.status === 401 || response.status === 403) {
      const error = apiError(response, data);
      authFailed(error, reading && Boolean(headers.Authorization));
      throw error;
    }
    if (!response.ok) throw apiError(response, data);
    return data;
  }

  // --- authentication banner: a refused token never clears or freezes the plots ----------

  function authFailed(error, readWithToken) {
    const banner = $("auth-banner");
    const what = state.token ? "The token was refused" : "A token is needed";
    const why = `${error.status} ${error.kind || ""}: ${error.message}`.replace(/ +:/, ":");
    let next;
    if (readWithToken && error.status === 401) {
      // an unknown token: read without it (the server may allow anonymous reading)
      if (!state.tokenRefused) {
        state.tokenRefused = true;
        connect();
      }
      next = "Reading on without it where the server allows: the plots keep what they show "
        + "and go on. Enter a valid token above to control the run.";
    } else if (state.tokenRefused && error.status === 401) {
      next = "Reading needs a valid token here: the plots keep what they show until one is "
        + "entered above.";
    } else if (!state.token) {
      next = "Enter a token above; the plots keep what they show.";
    } else {
      next = "Enter a token with the needed scope above; the plots keep what they show.";
    }
    banner.replaceChildren();
    const strong = document.createElement("strong");
    strong.textContent = `${what} (${why}). `;
    banner.append(strong, document.createTextNode(next));
    banner.hidden = false;
    banner.dataset.status = String(error.status);
  }

  function hideBanner() {
    $("auth-banner").hidden = true;
  }

  function say(text, isError = false) {
    const message = $("message");
    message.textContent = text;
    message.className = isError ? "error" : "ok";
  }

  function fail(error, doing) {
    const prefix = doing ? `${doing}: ` : "";
    const status = error.status ? `${error.status} ` : "";
    const kind = error.kind ? `${error.kind}: ` : "";
    let details = "";
    if (error.body && Array.isArray(error.body.details)) {
      details = error.body.details
        .map((d) => (d && d.field ? `${d.field}: ${d.message}` : JSON.stringify(d)))
        .join("; ");
    }
    const hint = error.status === 401 || error.status === 403 ? " (enter a control token)" : "";
    say(`${prefix}${status}${kind}${error.message}${details ? ` (${details})` : ""}${hint}`, true);
  }

  // --- plots -----------------------------------------------------------------------------

  // --- palette: every series its own colour -----------------------------------------------
  // Colours are picked greedily from a grid of hues and lightnesses, each the one farthest
  // (CIELAB distance) from those already chosen, so 17 model nodes and the IR regions stay
  // distinguishable; the nodes are also dashed and thin, the IR regions solid and thick.

  function hslToRgb(h, s, l) {
    const k = (n) => (n + h / 30) % 12;
    const a = s * Math.min(l, 1 - l);
    const f = (n) => l - a * Math.max(-1, Math.min(k(n) - 3, Math.min(9 - k(n), 1)));
    return [f(0), f(8), f(4)].map((v) => Math.round(v * 255));
  }

  function rgbToLab([r, g, b]) {
    const lin = (c) => { const v = c / 255; return v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
    const [R, G, B] = [lin(r), lin(g), lin(b)];
    const x = (0.4124 * R + 0.3576 * G + 0.1805 * B) / 0.95047;
    const y = 0.2126 * R + 0.7152 * G + 0.0722 * B;
    const z = (0.0193 * R + 0.1192 * G + 0.9505 * B) / 1.08883;
    const f = (t) => (t > 0.008856 ? Math.cbrt(t) : 7.787 * t + 16 / 116);
    return [116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))];
  }

  const hex = (rgb) => `#${rgb.map((v) => v.toString(16).padStart(2, "0")).join("")}`;

  const CANDIDATES = (() => {
    const list = [];
    for (let h = 0; h < 360; h += 6) {
      for (const [sat, light] of [[0.9, 0.32], [0.8, 0.42], [0.85, 0.52], [0.6, 0.25]]) {
        const rgb = hslToRgb(h, sat, light);
        const lab = rgbToLab(rgb);
        if (lab[0] >= 25 && lab[0] <= 68) list.push({ colour: hex(rgb), lab }); // on white
      }
    }
    return list;
  })();

  const distance = (p, q) => Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]);

  function palette(n) {
    const first = rgbToLab([31, 111, 235]); // the page's blue starts every palette
    const chosen = [];
    const taken = new Set();
    let nearest = CANDIDATES.map(() => Infinity); // distance to the closest chosen colour
    let pick = CANDIDATES.reduce((best, c, i) =>
      (distance(c.lab, first) < distance(CANDIDATES[best].lab, first) ? i : best), 0);
    while (chosen.length < n && chosen.length < CANDIDATES.length) {
      chosen.push(CANDIDATES[pick].colour);
      taken.add(pick);
      const lab = CANDIDATES[pick].lab;
      nearest = nearest.map((d, i) => Math.min(d, distance(CANDIDATES[i].lab, lab)));
      pick = -1;
      nearest.forEach((d, i) => { if (!taken.has(i) && (pick < 0 || d > nearest[pick])) pick = i; });
    }
    return chosen;
  }

  function makePlot(elementId, series) {
    const element = $(elementId);
    const data = [[], ...series.map(() => [])];
    const options = {
      width: Math.max(element.clientWidth, 300),
      height: 180,
      scales: { x: { time: false } },
      axes: [{ label: "run time (s)" }, {}],
      legend: { live: false },
      series: [{}, ...series.map((s) => ({
        label: s.name, stroke: s.colour, width: s.width || 1.5, dash: s.dash, spanGaps: true,
      }))],
    };
    return {
      plot: new uPlot(options, data, element),
      data,
      names: series.map((s) => s.name),
      colours: series.map((s) => s.colour),
      element,
    };
  }

  function xyzSeries() {
    const colours = palette(3);
    return ["x", "y", "z"].map((name, i) => ({ name, colour: colours[i] }));
  }

  const plots = {
    predicted: makePlot("plot-predicted", xyzSeries()),
    offset: makePlot("plot-offset", xyzSeries()),
    residual: makePlot("plot-residual", [{ name: "residual", colour: "#c62828" }]),
    temperature: null, // built on the first step, when the node names are known
    // arm runs (issue 20): the tool's measured 3-D drift and rotation error, norm and
    // components (base frame); built and shown on an arm run's first step
    drift3d: null,
    rotation: null,
  };

  function normSeries(norm) {
    const colours = palette(4);
    return [{ name: norm, colour: "#c62828", width: 2.5 },
      ...["x", "y", "z"].map((name, i) => ({ name, colour: colours[i + 1] }))];
  }

  function isArmStep(step) {
    return num(step.predicted_tx_um) !== null || num(step.drift_3d_um) !== null;
  }

  function num(value) {
    return value === null || value === undefined || value === "" ? null : Number(value);
  }

  function scaled(value, factor) {
    const n = num(value);
    return n === null ? null : n * factor;
  }

  function parsed(text) {
    try {
      const value = text ? JSON.parse(text) : {};
      return value && typeof value === "object" ? value : {};
    } catch { return {}; }
  }

  // every model node (dashed, thin) and every IR region (solid, thick), in natural order
  function temperatureSeries(step) {
    const nodes = Object.keys(parsed(step.model_temperatures_json)).sort(naturally);
    const regions = Object.keys(parsed(step.ir_json)).sort(naturally);
    const colours = palette(nodes.length + regions.length);
    return [
      ...nodes.map((node, i) => ({ name: `node ${node}`, colour: colours[i], dash: [6, 3] })),
      ...regions.map((region, i) => ({
        name: `IR ${region}`, colour: colours[nodes.length + i], width: 2.5,
      })),
    ];
  }

  function temperatureValues(step, names) {
    const model = parsed(step.model_temperatures_json);
    const ir = parsed(step.ir_json);
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
    for (const key of ["temperature", "drift3d", "rotation"]) {
      if (plots[key]) {
        plots[key].plot.destroy();
        plots[key] = null;
      }
    }
    $("arm-drift").hidden = true;
    $("arm-rotation").hidden = true;
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
    const arm = isArmStep(step);
    push(plots.predicted, t, arm
      ? [num(step.predicted_tx_um), num(step.predicted_ty_um), num(step.predicted_tz_um)]
      : [num(step.predicted_x_um), num(step.predicted_y_um), num(step.predicted_z_um)]);
    push(plots.offset, t, [scaled(step.offset_x_mm, 1000), scaled(step.offset_y_mm, 1000),
      scaled(step.offset_z_mm, 1000)]);
    push(plots.residual, t, [arm ? num(step.drift_3d_um) : num(step.residual_um)]);
    if (arm && !plots.drift3d) {
      $("arm-drift").hidden = false;
      $("arm-rotation").hidden = false;
      plots.drift3d = makePlot("plot-drift3d", normSeries("|drift|"));
      plots.rotation = makePlot("plot-rotation", normSeries("|rotation|"));
    }
    if (plots.drift3d) {
      push(plots.drift3d, t, [num(step.drift_3d_um), num(step.measured_tx_um),
        num(step.measured_ty_um), num(step.measured_tz_um)]);
      push(plots.rotation, t, [num(step.rotation_error_urad), num(step.measured_rx_urad),
        num(step.measured_ry_urad), num(step.measured_rz_urad)]);
    }
    if (!plots.temperature) {
      const series = temperatureSeries(step);
      if (series.length) plots.temperature = makePlot("plot-temperature", series);
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
      $("run-id").textContent = String(run.id);
      showRunState($("run-state"), run);
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
    showRobot(snapshot.robot);
    const active = ACTIVE_STATES.includes(daemonState);
    $("btn-start").disabled = active;
    $("btn-pause").disabled = daemonState !== "running";
    $("btn-resume").disabled = !["paused", "fault"].includes(daemonState);
    $("btn-stop").disabled = !active;
  }

  // A run's state in the API's own word (finished, stopped, aborted, fault, interrupted, or
  // an active state), its reason on hover and, on click, in the message line.
  function showRunState(element, run) {
    element.textContent = run.state;
    element.className = `state ${run.state}`;
    element.dataset.reason = run.reason || "";
    element.title = run.reason ? `${run.state}: ${run.reason}` : `${run.state} (no reason given)`;
    element.dataset.runId = String(run.id);
  }

  function explainState(event) {
    const element = event.target.closest(".state");
    if (!element || !element.dataset.runId) return;
    const reason = element.dataset.reason;
    say(`run ${element.dataset.runId} ${element.textContent}: ${reason || "no reason given"}`);
  }

  // --- badges: robot held, waiting for the operator, device states -----------------------

  function badge(text, kind, title) {
    const element = document.createElement("span");
    element.className = `badge ${kind}`;
    element.textContent = text;
    if (title) element.title = title;
    return element;
  }

  function showRobot(robot) {
    const badges = [];
    if (robot && robot.motion_held) {
      badges.push(badge("robot held", "held",
        "no motion command can be sent until the run is resumed (or a new run starts)"));
    }
    if (robot && robot.link === "awaiting-point-of-control") {
      badges.push(badge("waiting for the operator: press PAUSE/CONTINUE", "waiting",
        "the controller waits for the point of control: press PAUSE/CONTINUE on the teach "
        + "pendant (docs/reference/c500c-console.md)"));
    }
    $("robot-badges").replaceChildren(...badges);
  }

  function deviceKind(text) {
    if (/error|fault|disconnected/.test(text)) return "bad";
    if (/stale|reconnecting|connecting|awaiting/.test(text)) return "warn";
    return "good";
  }

  async function refreshHealth() {
    try {
      const response = await fetch(`${API}/health`, { headers: { Accept: "application/json" } });
      const health = await response.json();
      const devices = Object.entries(health.devices || {}).sort(([a], [b]) => naturally(a, b));
      $("device-badges").replaceChildren(...devices.map(([name, text]) =>
        badge(`${name}: ${text}`, `device ${deviceKind(String(text))}`)));
    } catch { /* health is a convenience; the state and errors say the rest */ }
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
      if (![401, 403, 404].includes(error.status)) fail(error, "loading the run's steps");
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
      if (![401, 403, 503].includes(error.status)) fail(error, "loading the run history");
    }
  }

  // What the summary's reduction is measured against (issue 19): a measured uncompensated
  // reference run, else only the model's prediction; an uncompensated run has its drift.
  function reductionText(summary) {
    const number = (value, digits) =>
      value === undefined || value === null ? null : Number(value).toFixed(digits);
    if (summary.drift_3d_max_um !== undefined) { // an arm run: the 3-D drift and rotation
      const drift = number(summary.drift_3d_max_um, 2);
      const rotation = number(summary.rotation_error_max_urad, 1);
      const reduction = number(summary.reduction_3d_percent, 1);
      const text = `3-D ${drift === null ? "–" : drift} µm, rot ${rotation === null ? "–" : rotation} µrad`;
      return reduction === null ? text : `${text}, ${reduction} % vs run ${summary.reference_run}`;
    }
    if (summary.reduction_basis === "drift") {
      const drift = number(summary.measured_drift_max_um, 2);
      return drift === null ? "–" : `drift ${drift} µm (off)`;
    }
    if (summary.reduction_basis === "reference") {
      const measured = number(summary.reduction_percent, 1);
      return measured === null ? "–" : `${measured} % vs run ${summary.reference_run}`;
    }
    // no reference run: relative to the prediction (older summaries had it as reduction_percent)
    const predicted = number(
      summary.reduction_basis === "prediction"
        ? summary.reduction_vs_prediction_percent : summary.reduction_percent, 1);
    return predicted === null ? "–" : `${predicted} % vs model`;
  }

  function residualText(summary) {
    const value = summary.drift_3d_max_um !== undefined
      ? summary.drift_3d_max_um : summary.residual_max_um; // an arm run: its 3-D residual
    return value === undefined || value === null ? "–" : Number(value).toFixed(2);
  }

  function historyRow(run) {
    const row = document.createElement("tr");
    const summary = run.summary || {};
    const cells = [
      String(run.id),
      null, // the state: its word, with its reason on hover and click
      new Date(run.started_at * 1000).toLocaleString(),
      String(run.steps_recorded),
      residualText(summary),
      reductionText(summary),
    ];
    for (const text of cells) {
      const cell = document.createElement("td");
      if (text === null) {
        const word = document.createElement("span");
        showRunState(word, run);
        cell.append(word);
      } else {
        cell.textContent = text;
      }
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
    } catch { /* a refused token shows the banner (authFailed); the poll tries again */ }
  }

  // --- camera frame -----------------------------------------------------------------------

  // The stream's thumbnail is the frame reduced by `scale` (each pixel the brightest of a
  // scale x scale block). A small spot on a dark frame is lost at that size, so the view
  // shows a crop around the centroid, enlarged and contrast-stretched over the crop alone;
  // a click switches to the whole frame (with the crop outlined) and back.
  const CROP_PX = 16; // thumbnail pixels each side of the crop (16 x 4 = 64 frame pixels)
  const ZOOM_CANVAS_PX = 256;
  const frameView = { image: null, crop: null, frame: null, full: false };

  function showFrame(frame) {
    // the thumbnail, and (when the spot was found) the server's full-resolution crop around it
    const image = new Image();
    const crop = frame.crop_png_base64 ? new Image() : null;
    let pending = crop ? 2 : 1;
    const loaded = () => {
      pending -= 1;
      if (pending > 0) return;
      frameView.image = image;
      frameView.crop = crop;
      frameView.frame = frame;
      drawFrame();
    };
    image.onload = loaded;
    image.src = `data:image/png;base64,${frame.png_base64}`;
    if (crop) {
      crop.onload = loaded;
      crop.src = `data:image/png;base64,${frame.crop_png_base64}`;
    }
  }

  function drawCrop(canvas, context, frame, crop, x, y) {
    // the server's crop: full resolution, already contrast-stretched over the crop itself
    const size = Number(frame.crop_size_px);
    canvas.width = ZOOM_CANVAS_PX;
    canvas.height = ZOOM_CANVAS_PX;
    context.imageSmoothingEnabled = false;
    context.drawImage(crop, 0, 0, ZOOM_CANVAS_PX, ZOOM_CANVAS_PX);
    const zoom = ZOOM_CANVAS_PX / size;
    // frame pixel centres are at integers: pixel c spans c - 0.5 .. c + 0.5
    const cx = (x - Number(frame.crop_x0_px) + 0.5) * zoom;
    const cy = (y - Number(frame.crop_y0_px) + 0.5) * zoom;
    cross(context, cx, cy, 1.5 * zoom, 5 * zoom);
    canvas.dataset.view = "zoom";
    canvas.dataset.contrast = `${Math.round(frame.crop_low)}-${Math.round(frame.crop_high)}`;
    $("frame-detail").textContent = `zoom around the spot: ${size} x ${size} frame px at full `
      + "resolution, contrast stretched over the crop; click for the full frame";
  }

  function cross(context, cx, cy, gap, arm) {
    // a cross with a gap in the middle, so the spot itself stays visible
    context.strokeStyle = "#ff3b30";
    context.lineWidth = 1.5;
    context.beginPath();
    for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) {
      context.moveTo(cx + gap * dx, cy + gap * dy);
      context.lineTo(cx + arm * dx, cy + arm * dy);
    }
    context.stroke();
  }

  function cropOrigin(frame, cx, cy) {
    const clamp = (v, size) => Math.max(0, Math.min(Math.round(v - CROP_PX / 2), size - CROP_PX));
    return [clamp(cx, frame.width), clamp(cy, frame.height)];
  }

  function drawFrame() {
    const { image, frame } = frameView;
    if (!image || !frame) return;
    const canvas = $("frame-canvas");
    const context = canvas.getContext("2d");
    const x = num(frame.centroid_x_px);
    const y = num(frame.centroid_y_px);
    const scale = Number(frame.scale) || 1;
    // frame pixel centres are at integers; thumbnail pixel (r, c) covers scale x scale pixels
    const cx = x === null ? null : (x + 0.5) / scale;
    const cy = y === null ? null : (y + 0.5) / scale;
    const where = x === null ? "no centroid" : `centroid (${x.toFixed(2)}, ${y.toFixed(2)}) px`;
    $("frame-caption").textContent = `run ${frame.run_id} step ${frame.step}: ${where}`;
    const small = frame.width < CROP_PX || frame.height < CROP_PX;
    if (frameView.full || cx === null || small) {
      canvas.width = frame.width;
      canvas.height = frame.height;
      context.imageSmoothingEnabled = false;
      context.drawImage(image, 0, 0);
      if (cx !== null) {
        cross(context, cx, cy, 4, 12);
        if (!small) {
          const [sx, sy] = cropOrigin(frame, cx, cy);
          context.strokeStyle = "#ffd60a";
          context.lineWidth = 1;
          context.strokeRect(sx + 0.5, sy + 0.5, CROP_PX - 1, CROP_PX - 1);
        }
      }
      canvas.dataset.view = "full";
      $("frame-detail").textContent = `full frame, reduced 1:${scale} (${frame.width} x `
        + `${frame.height} px)${cx === null ? "" : "; yellow: the zoomed area; click to zoom"}`;
      return;
    }
    if (frameView.crop) {
      drawCrop(canvas, context, frame, frameView.crop, x, y);
      return;
    }
    const [sx, sy] = cropOrigin(frame, cx, cy);
    const scratch = document.createElement("canvas");
    scratch.width = CROP_PX;
    scratch.height = CROP_PX;
    const crop = scratch.getContext("2d");
    crop.drawImage(image, sx, sy, CROP_PX, CROP_PX, 0, 0, CROP_PX, CROP_PX);
    const pixels = crop.getImageData(0, 0, CROP_PX, CROP_PX);
    let low = 255;
    let high = 0;
    for (let i = 0; i < pixels.data.length; i += 4) {
      low = Math.min(low, pixels.data[i]);
      high = Math.max(high, pixels.data[i]);
    }
    const span = Math.max(high - low, 1);
    for (let i = 0; i < pixels.data.length; i += 4) {
      const v = Math.round(((pixels.data[i] - low) * 255) / span);
      pixels.data[i] = v;
      pixels.data[i + 1] = v;
      pixels.data[i + 2] = v;
    }
    crop.putImageData(pixels, 0, 0);
    canvas.width = ZOOM_CANVAS_PX;
    canvas.height = ZOOM_CANVAS_PX;
    context.imageSmoothingEnabled = false;
    context.drawImage(scratch, 0, 0, ZOOM_CANVAS_PX, ZOOM_CANVAS_PX);
    const zoom = ZOOM_CANVAS_PX / CROP_PX;
    cross(context, (cx - sx) * zoom, (cy - sy) * zoom, 2 * zoom, 6 * zoom);
    canvas.dataset.view = "zoom";
    canvas.dataset.contrast = `${low}-${high}`;
    $("frame-detail").textContent = `zoom around the spot: ${CROP_PX * scale} x ${CROP_PX * scale}`
      + ` frame px, contrast stretched over the crop; click for the full frame`;
  }

  $("frame-canvas").addEventListener("click", () => {
    frameView.full = !frameView.full;
    drawFrame();
  });

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
    if (state.token && !state.tokenRefused) protocols.push(`bearer.${base64url(state.token)}`);
    const socket = new WebSocket(`${scheme}://${location.host}${API}/ws?${query}`, protocols);
    state.socket = socket;
    const badge = $("stream-state");
    socket.onopen = () => {
      badge.textContent = "open";
      badge.className = "badge open";
      state.reconnectDelay = 500;
    };
    let opened = false;
    socket.addEventListener("open", () => { opened = true; });
    socket.onclose = () => {
      if (state.socket !== socket) return;
      badge.textContent = "closed";
      badge.className = "badge closed";
      // a refused handshake hides its HTTP status from scripts: a read of /state tells why
      if (!opened) refreshState();
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

  // Each action answers with what happened, or with the API's own error message.
  function control(doing, path, describe) {
    return async () => {
      try {
        const answer = await api("POST", path());
        say(describe(answer));
      } catch (error) {
        fail(error, doing);
      }
      await refreshState();
      refreshHistory();
    };
  }

  function atStep(run) {
    const recorded = Number(run.steps_recorded);
    const step = Math.max(state.lastStep, Number.isFinite(recorded) ? recorded - 1 : -1);
    return step >= 0 ? `at step ${step}` : "before its first step";
  }

  const why = (run) => (run.reason ? ` (${run.reason})` : "");

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
      say(`run ${run.id} ${run.state === "starting" ? "starting" : "started"}: `
        + `${run.parameters.procedure || ""} ${run.parameters.duration_s} s, `
        + `step ${run.parameters.step_s} s`);
      state.runId = run.id;
      resetPlots();
      await refreshState();
      await refreshHistory();
    } catch (error) {
      fail(error, "start refused");
    }
  });

  $("btn-pause").addEventListener("click", control("pause refused",
    () => `/runs/${state.runId}/pause`, (run) => `run ${run.id} paused ${atStep(run)}`));
  $("btn-resume").addEventListener("click", control("resume refused",
    () => `/runs/${state.runId}/resume`, (run) => `run ${run.id} resumed ${atStep(run)}`));
  $("btn-stop").addEventListener("click", control("stop refused",
    () => `/runs/${state.runId}/stop`,
    (run) => `run ${run.id} ${run.state} after ${run.steps_recorded} steps${why(run)}`));
  $("btn-hold").addEventListener("click", control("hold failed", () => "/robot/stop",
    (hold) => (hold.held
      ? `hold acknowledged: no motion can be sent (daemon ${hold.state})`
      : `the robot is not held (daemon ${hold.state})`)));

  // the bring-up preview (issue 18): a PNG, fetched with the token like every read
  $("btn-preview").addEventListener("click", async () => {
    const headers = {};
    if (state.token && !state.tokenRefused) headers.Authorization = `Bearer ${state.token}`;
    try {
      const response = await fetch(`${API}/devices/preview`, { headers });
      if (!response.ok) {
        const text = await response.text();
        let data = null;
        try { data = JSON.parse(text); } catch { data = { message: text }; }
        throw apiError(response, data);
      }
      const image = $("preview-image");
      if (image.src) URL.revokeObjectURL(image.src);
      image.src = URL.createObjectURL(await response.blob());
      image.hidden = false;
      const spot = response.headers.get("X-Thermocomp-Spot-Px");
      const errors = response.headers.get("X-Thermocomp-Device-Errors");
      $("preview-caption").textContent = (spot ? `spot at (${spot}) px` : "no spot found")
        + (errors ? `; device errors: ${errors}` : "");
      say("preview: one frame, one IR image and the robot pose");
    } catch (error) {
      fail(error, "preview refused");
    }
  });

  $("run-history").addEventListener("click", explainState);
  $("run-state").addEventListener("click", explainState);

  $("token").value = state.token;
  $("token-form").addEventListener("submit", (event) => {
    event.preventDefault();
    state.token = $("token").value.trim();
    state.tokenRefused = false;
    hideBanner();
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
        const found = network.identification;
        // an identified network says where it came from (issue 19): its source runs and date
        option.textContent = found
          ? `${network.name} (identified from ${found.source_runs.join(", ")})`
          : network.name;
        option.title = found
          ? `${network.description}\nidentified ${found.identified_at} from ${found.base_network}`
          : network.description;
        select.append(option);
      }
    } catch { /* the list is a convenience; the config's network is the default */ }
  }

  // an arm daemon (arm.enabled, issue 20): the identified arm models saved in the data
  // directory, each saying where it came from; a two-link daemon hides the field
  async function loadArmModels() {
    try {
      const list = await api("GET", "/arm-models");
      if (!list.arm_runs) return;
      const select = $("arm-model-select");
      for (const model of list.arm_models) {
        const option = document.createElement("option");
        option.value = model.name;
        option.textContent = `${model.name} (identified from ${model.source_runs.join(", ")})`;
        const fit = model.marker_rms_um === null
          ? "" : `, fit RMS ${model.marker_rms_um.toFixed(2)} µm`;
        option.title = `arm ${model.arm}, duty cycle ${model.duty_cycle}, identified `
          + `${model.identified_at}${fit}`;
        select.append(option);
      }
      $("arm-model-field").hidden = false;
    } catch { /* the list is a convenience; without it a run uses the preset arm's model */ }
  }

  // exposed for the browser test and for curious users in the console
  window.thermocomp = { state, plots };

  // the stream carries steps and state changes; a slow poll keeps timing, the robot's badges,
  // the devices and the history fresh (the robot may be held or wait while no run is active)
  setInterval(() => {
    refreshState();
    refreshHealth();
    if (ACTIVE_STATES.includes(state.daemonState)) refreshHistory();
  }, POLL_MS);

  requestAnimationFrame(redraw);
  connect();
  refreshState();
  refreshHistory();
  refreshHealth();
  loadNetworks();
  loadArmModels();
})();
