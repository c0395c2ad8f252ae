// thermocomp dashboard: one page, no build step. Talks to /api/v1 (REST) and /api/v1/ws.
// Every value from the daemon reaches the page through textContent, never as HTML.
import {
  api, auth, fail, hideBanner, say, setToken, takeTokenFromAddress, whenReadRefused,
} from "./api.js";
import { clearAdaptation, showAdaptation } from "./adaptation.js";
import { clearCameras, preview, showFrame } from "./camera.js";
import { addError, showErrors } from "./errors.js";
import { explainState, historyRow, showRunState } from "./history.js";
import { headline, showDoing } from "./headline.js";
import { adaptForm, loadChoices, offerReferences, startBody } from "./form.js";
import { fill, kinds, loadKinds, startedView, viewOf } from "./kinds.js";
import { RunPlots } from "./runplots.js";
import { $, element } from "./util.js";

const POLL_MS = 3000; // state, history, device health and the headline, besides the stream
const RENDER_MS = 250; // plots are redrawn at most this often
// the daemon's states while a run is under way; anything else is idle or a final word
const ACTIVE_STATES = ["starting", "running", "paused", "stopping", "fault"];

takeTokenFromAddress();

const state = {
  runId: null, // the run the plots show
  shownRun: null, // its record (GET /runs/{id})
  daemonState: "idle",
  lastStep: -1,
  durationS: null,
  socket: null,
  reconnectDelay: 500,
  lost: 0,
  steps: 0,
  seen: new Set(), // the shown run's steps already plotted (stream and backfill overlap)
  history: [],
  snapshot: null,
};
const plots = new RunPlots();

// --- which run the plots show -----------------------------------------------------------

async function showRun(run, { backfill = true } = {}) {
  state.runId = run.id;
  state.shownRun = run;
  state.lastStep = -1;
  state.steps = 0;
  state.seen = new Set();
  // a run whose kind is not known (recorded before runs said their kind) is drawn as this
  // daemon's runs are
  plots.reset(viewOf(run) || startedView(), run.parameters || {});
  clearCameras();
  clearAdaptation();
  $("no-run").hidden = true;
  $("plots").classList.remove("empty");
  $("shown-run").textContent = `plots: run ${run.id} (${run.state})`;
  const reference = run.parameters && run.parameters.reference_run;
  if (reference) loadReference(run.id, reference);
  if (backfill) await loadSteps(run.id);
  headline.refresh(run, state);
  markShown();
}

async function allSteps(runId, stillWanted) {
  // JSON pages are capped (5,000 steps): follow next_from up to the plot's capacity
  const steps = [];
  let from = 0;
  while (from !== null && steps.length < 20000) {
    const page = await api("GET", `/runs/${runId}/steps?format=json&from=${from}&limit=5000`);
    if (!stillWanted()) return null;
    steps.push(...page.steps);
    from = page.next_from;
  }
  return steps;
}

async function loadSteps(runId) {
  try {
    const steps = await allSteps(runId, () => state.runId === runId);
    if (!steps) return;
    for (const step of steps) addStep(step);
  } catch (error) {
    if (![401, 403, 404].includes(error.status)) fail(error, "loading the run's steps");
  }
}

async function loadReference(runId, referenceId) {
  try {
    const steps = await allSteps(referenceId, () => state.runId === runId);
    if (steps) plots.setReference(referenceId, steps);
  } catch (error) {
    if (![401, 403, 404].includes(error.status)) fail(error, "loading the reference run");
  }
}

function addStep(step) {
  if (step.run_id !== state.runId || state.seen.has(step.step)) return; // once per step
  state.seen.add(step.step);
  plots.addStep(step);
  if (plots.view && plots.view.adaptation) showAdaptation(step);
  state.lastStep = Math.max(state.lastStep, step.step);
  state.steps += 1;
  $("run-step").textContent = String(state.lastStep);
}

let lastRender = 0;
function redraw(now) {
  if (now - lastRender >= RENDER_MS) {
    lastRender = now;
    plots.render();
  }
  requestAnimationFrame(redraw);
}

let resizing = null;
window.addEventListener("resize", () => {
  clearTimeout(resizing);
  resizing = setTimeout(() => plots.resize(), 100);
});

// --- state, errors, history ------------------------------------------------------------

// The start's message ("run 2 starting: ...") stays under the buttons until something else is
// said: when that run ends by itself (finished, aborted, fault), the message says so.
function endOfStart(run) {
  const message = $("message");
  const started = message.textContent.startsWith(`run ${run.id} start`);
  if (started && !ACTIVE_STATES.includes(run.state)) {
    // the state's run gives its last step's index (GET /runs/{id} gives steps_recorded)
    const given = (value) => value !== null && value !== undefined && Number.isFinite(+value);
    const recorded = given(run.steps_recorded) ? Number(run.steps_recorded)
      : given(run.step) ? Number(run.step) + 1 : 0;
    say(`run ${run.id} ${run.state} after ${recorded} steps${
      run.reason ? ` (${run.reason})` : ""}`, run.state !== "finished");
  }
}

function showState(snapshot) {
  if (!snapshot) return;
  state.snapshot = snapshot;
  const daemonState = snapshot.state || "idle";
  state.daemonState = daemonState;
  const badge = $("daemon-state");
  badge.textContent = daemonState;
  badge.className = `badge ${daemonState}`;
  const run = snapshot.run;
  if (run) {
    $("run-id").textContent = String(run.id);
    showRunState($("run-state"), run);
    if (state.runId !== run.id && (ACTIVE_STATES.includes(run.state) || state.runId === null)) {
      showRun(run); // a new run (or the page's first state): its plots, backfilled
    }
    state.durationS = run.parameters ? Number(run.parameters.duration_s) : null;
    showProgress(Number(run.progress_percent || 0));
    endOfStart(run);
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
  $("btn-preview").disabled = active;
  showDoing(snapshot, state);
}

function badge(text, kind, title) {
  const node = element("span", `badge ${kind}`, text);
  if (title) node.title = title;
  return node;
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
  if (text === "none") return "absent"; // a sensor the robot does without: grey, not green
  if (/error|fault|disconnected/.test(text)) return "bad";
  if (/stale|reconnecting|connecting|awaiting/.test(text)) return "warn";
  return "good";
}

async function refreshHealth() {
  try {
    const response = await fetch("/api/v1/health", { headers: { Accept: "application/json" } });
    const health = await response.json();
    const devices = Object.entries(health.devices || {}).sort(([a], [b]) => a.localeCompare(b));
    $("device-badges").replaceChildren(...devices.map(([name, text]) =>
      badge(`${name}: ${text}`, `device ${deviceKind(String(text))}`)));
    if (health.devices && health.devices.camera === "none") {
      // a robot followed by its own joint temperatures (a UR): no camera to show
      $("frame-caption").textContent = "no camera: this robot's tool is not watched; its "
        + "joint temperatures are the thermal input";
    }
  } catch { /* health is a convenience; the state and errors say the rest */ }
}

function showProgress(percent) {
  $("run-progress").value = percent;
  $("run-progress-text").textContent = `${percent.toFixed(1)} %`;
}

function markShown() {
  for (const row of $("run-history").children) {
    row.classList.toggle("shown", row.firstChild.textContent === String(state.runId));
  }
}

async function refreshHistory() {
  try {
    const page = await api("GET", "/runs?limit=20");
    state.history = page.runs;
    $("run-history").replaceChildren(...page.runs.map((run) => historyRow(run,
      { onPlot: (chosen) => showRun(chosen), shown: run.id === state.runId })));
    offerReferences(page.runs, startedView());
    const none = !page.runs.length && state.runId === null;
    $("no-run").hidden = !none; // a first start: what to do, instead of empty plots
    $("plots").classList.toggle("empty", none);
    if (state.runId === null && page.runs.length) {
      showRun(page.runs[0]); // after a restart: the newest run's plots, from the database
    } else if (state.shownRun) {
      const fresh = page.runs.find((run) => run.id === state.runId);
      if (fresh) state.shownRun = fresh;
    }
  } catch (error) {
    if (![401, 403, 503].includes(error.status)) fail(error, "loading the run history");
  }
}

async function refreshState() {
  try {
    showState(await api("GET", "/state"));
  } catch { /* a refused token shows the banner (authFailed); the poll tries again */ }
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
  if (auth.token && !auth.refused) protocols.push(`bearer.${base64url(auth.token)}`);
  const socket = new WebSocket(`${scheme}://${location.host}/api/v1/ws?${query}`, protocols);
  state.socket = socket;
  const streamBadge = $("stream-state");
  let opened = false;
  socket.onopen = () => {
    opened = true;
    streamBadge.textContent = "open";
    streamBadge.className = "badge open";
    state.reconnectDelay = 500;
  };
  socket.onclose = () => {
    if (state.socket !== socket) return;
    streamBadge.textContent = "closed";
    streamBadge.className = "badge closed";
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
      case "state": refreshState(); refreshHistory(); headline.poll(state, true); break;
      case "error": addError(message.data); break;
      case "frame": if (message.data.run_id === state.runId) showFrame(message.data); break;
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
whenReadRefused(connect);

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
  try {
    const run = await api("POST", "/runs", startBody(event.target));
    const p = run.parameters;
    const what = fill((viewOf(run) || {}).what_text, p) || run.kind;
    say(`run ${run.id} ${run.state === "starting" ? "starting" : "started"}: ${what}, `
      + `${p.compensation}, ${p.duration_s} s, step ${p.step_s} s`);
    await showRun(run, { backfill: false });
    await refreshState();
    await refreshHistory();
  } catch (error) {
    fail(error, "start refused");
  }
});

$("btn-pause").addEventListener("click", control("pause refused",
  () => `/runs/${state.snapshot.run.id}/pause`, (run) => `run ${run.id} paused ${atStep(run)}`));
$("btn-resume").addEventListener("click", control("resume refused",
  () => `/runs/${state.snapshot.run.id}/resume`, (run) => `run ${run.id} resumed ${atStep(run)}`));
$("btn-stop").addEventListener("click", control("stop refused",
  () => `/runs/${state.snapshot.run.id}/stop`,
  (run) => `run ${run.id} ${run.state} after ${run.steps_recorded} steps${why(run)}`));
$("btn-hold").addEventListener("click", control("hold failed", () => "/robot/stop",
  (hold) => (hold.held
    ? `hold acknowledged: no motion can be sent (daemon ${hold.state})`
    : `the robot is not held (daemon ${hold.state})`)));
$("btn-preview").addEventListener("click", preview);

$("run-history").addEventListener("click", explainState);
$("run-state").addEventListener("click", explainState);

$("token").value = auth.token;
$("token-form").addEventListener("submit", (event) => {
  event.preventDefault();
  setToken($("token").value.trim());
  hideBanner();
  say(auth.token ? "token set" : "token cleared");
  connect();
  refreshState();
  refreshHistory();
});

// exposed for the browser test and for curious users in the console
window.thermocomp = { state, plots: null, auth };
Object.defineProperty(window.thermocomp, "plots", { get: () => plots.charts });

// The kinds' views (GET /kinds): the form, the plots and the runs table render from them. Read
// again by the poll while they could not be read (a token refused for reading).
async function ensureKinds() {
  if (kinds.loaded || !(await loadKinds())) return;
  adaptForm(startedView());
  if (state.shownRun) showRun(state.shownRun);
  else plots.reset(startedView());
  if (state.history.length) refreshHistory();
}

async function start() {
  await Promise.all([ensureKinds(), loadChoices()]);
  if (auth.fromAddress && auth.token) say("control token taken from the address");
  requestAnimationFrame(redraw);
  connect();
  await refreshState();
  await refreshHistory();
  refreshHealth();
  headline.poll(state);
  // the stream carries steps and state changes; a slow poll keeps timing, the robot's
  // badges, the devices, the headline and the history fresh
  setInterval(() => {
    ensureKinds();
    refreshState();
    refreshHealth();
    headline.poll(state);
    if (ACTIVE_STATES.includes(state.daemonState)) refreshHistory();
  }, POLL_MS);
}

start();
