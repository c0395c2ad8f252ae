// The runs table: what each run did (as its kind's view describes it, GET /kinds), its state
// (its reason on hover and click), its figures and its data; "plot" shows a past run's steps
// from the database.
import { authHeaders, say } from "./api.js";
import { fill, viewOf } from "./kinds.js";
import { element, fixed } from "./util.js";

// A run's state in the API's own word (finished, stopped, aborted, fault, interrupted, or
// an active state), its reason on hover and, on click, in the message line.
export function showRunState(node, run) {
  node.textContent = run.state;
  node.className = `state ${run.state}`;
  node.dataset.reason = run.reason || "";
  node.title = run.reason ? `${run.state}: ${run.reason}` : `${run.state} (no reason given)`;
  node.dataset.runId = String(run.id);
}

export function explainState(event) {
  const node = event.target.closest(".state");
  if (!node || !node.dataset.runId) return;
  const reason = node.dataset.reason;
  say(`run ${node.dataset.runId} ${node.textContent}: ${reason || "no reason given"}`);
}

// What the summary's reduction is measured against (issue 19): a measured uncompensated
// reference run, else only the model's prediction; an uncompensated run has its drift. A
// negative figure is no reduction: it is said as such.
export function reductionText(summary) {
  const percent = (value, against) => (value < 0
    ? `none: error above ${against}` : `${Number(value).toFixed(1)} % vs ${against}`);
  if (summary.drift_3d_max_um !== undefined) { // a tool's figures: 3-D drift and rotation
    if (summary.reduction_basis === "drift") {
      const drift = fixed(summary.drift_3d_max_um, 1);
      return drift === null ? "–" : `drift ${drift} µm (off)`;
    }
    const reduction = summary.reduction_3d_percent;
    return reduction === null || reduction === undefined ? "no reference run"
      : percent(reduction, `run ${summary.reference_run}`);
  }
  if (summary.reduction_basis === "drift") {
    const drift = fixed(summary.measured_drift_max_um, 2);
    return drift === null ? "–" : `drift ${drift} µm (off)`;
  }
  if (summary.reduction_basis === "reference") {
    const measured = summary.reduction_percent;
    return measured === null || measured === undefined ? "–"
      : percent(measured, `run ${summary.reference_run}`);
  }
  // no reference run: relative to the prediction (older summaries had it as reduction_percent)
  const predicted = summary.reduction_basis === "prediction"
    ? summary.reduction_vs_prediction_percent : summary.reduction_percent;
  return predicted === null || predicted === undefined ? "–" : percent(predicted, "model");
}

function residualText(summary) {
  if (summary.drift_3d_max_um !== undefined) { // a tool's figures: 3-D drift and rotation
    const rotation = fixed(summary.rotation_error_max_urad, 0);
    return `3-D ${fixed(summary.drift_3d_max_um, 2) || "–"}, rot ${rotation || "–"} µrad`;
  }
  return fixed(summary.residual_max_um, 2) || "–";
}

// what it did and with which model, as its kind's view says; a run whose kind is not known
// (recorded before runs said their kind) says so rather than have one guessed
function whatText(run) {
  const view = viewOf(run);
  if (!view) {
    return run.kind ? `${run.kind} (a kind this daemon does not know)` : "kind not recorded";
  }
  const what = fill(view.what_text, run.parameters) || view.name;
  return `${what}${fill(view.model_text, run.parameters)}`;
}

function compensationText(run) {
  const p = run.parameters || {};
  const reference = p.reference_run ? ` vs run ${p.reference_run}` : "";
  return `${p.compensation || "–"}${reference}`;
}

function durationText(run) {
  const p = run.parameters || {};
  const step = Number(p.step_s) || 0;
  const done = run.steps_recorded * step;
  const hours = (seconds) => (seconds >= 3600 ? `${(seconds / 3600).toFixed(1)} h`
    : seconds >= 120 ? `${(seconds / 60).toFixed(0)} min` : `${seconds.toFixed(0)} s`);
  const scale = Number(p.time_scale) || 1;
  const view = viewOf(run);
  const scaled = view && view.scaled_time_text && scale !== 1
    ? ` (${hours(done * scale)} ${view.scaled_time_text})` : "";
  return `${hours(done)} of ${hours(Number(p.duration_s) || 0)}${scaled}`;
}

export function historyRow(run, { onPlot, shown }) {
  const row = element("tr");
  if (shown) row.className = "shown";
  const summary = run.summary || {};
  const cells = [
    String(run.id),
    null, // the state: its word, with its reason on hover and click
    whatText(run),
    compensationText(run),
    new Date(run.started_at * 1000).toLocaleString(),
    durationText(run),
    String(run.steps_recorded),
    residualText(summary),
    reductionText(summary),
  ];
  for (const text of cells) {
    const cell = element("td");
    if (text === null) {
      const word = element("span");
      showRunState(word, run);
      cell.append(word);
    } else {
      cell.textContent = text;
    }
    row.append(cell);
  }
  const links = element("td");
  const plot = element("button", "link", "plot");
  plot.title = "show this run's steps in the plots";
  plot.addEventListener("click", () => onPlot(run));
  links.append(plot);
  for (const [label, href] of [["CSV", run.links.steps_csv],
    ["Parquet", run.links.steps_parquet], ["report", run.links.report]]) {
    if (!href) continue; // no Parquet link when the server lacks the optional pyarrow
    const link = element("a", "", label);
    link.href = href;
    link.addEventListener("click", (event) => { event.preventDefault(); download(href, run.id); });
    links.append(link);
  }
  row.append(links);
  return row;
}

// Links carry the token in a header, so they are fetched and handed over as a blob.
async function download(href, runId) {
  const response = await fetch(href, { headers: authHeaders() });
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
