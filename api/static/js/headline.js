// The two lines at the top: what the robot is doing now, and whether the compensation works
// (the server's "drift removed so far", GET /runs/{id}/drift-removed).
import { api } from "./api.js";
import { fill, viewOf } from "./kinds.js";
import { $ } from "./util.js";

const ACTIVE_STATES = ["starting", "running", "paused", "stopping", "fault"];

export function showDoing(snapshot, state) {
  const run = snapshot.run;
  const robot = snapshot.robot || {};
  const doing = $("doing");
  let text;
  let tone = "idle";
  if (run && ACTIVE_STATES.includes(run.state)) {
    const p = run.parameters || {};
    const what = fill((viewOf(run) || {}).doing_text, p) || "its run";
    const compensation = p.compensation === "off" ? "no compensation (measuring the drift)"
      : `${p.compensation} compensation`;
    const progress = `${Number(run.progress_percent || 0).toFixed(0)} % of ${p.duration_s} s`;
    text = `Run ${run.id} ${run.state}: ${what}, ${compensation}; ${progress}`;
    if (run.state === "running" || run.state === "starting") tone = "running";
    else tone = "paused";
    if (run.reason && run.state !== "running") text += ` (${run.reason})`;
  } else {
    text = "Idle: no run; the robot is not being moved";
    if (run) text += ` (last: run ${run.id} ${run.state})`;
  }
  if (robot.motion_held) {
    // after a run the robot stays held until the next one starts: normal, said calmly; during
    // a run (a hold, a fault) it is what the operator must see first
    text += tone === "idle" ? ". The robot is held: no motion can be sent until a run starts"
      : ". Robot HELD: no motion command can be sent";
    tone = tone === "idle" ? "held-idle" : "held";
  }
  if (robot.link === "awaiting-point-of-control") {
    text += ". The controller waits for PAUSE/CONTINUE on the teach pendant";
    tone = "held";
  }
  doing.textContent = `${text}.`;
  doing.className = `doing ${tone}`;
  const shown = state.shownRun;
  $("shown-run").textContent = shown ? `plots: run ${shown.id} (${shown.state})` : "plots: –";
}

export const headline = {
  last: null, // [run id, steps] the figure shown covers
  async poll(state, force = false) {
    const run = state.shownRun;
    if (!run) return;
    const active = ACTIVE_STATES.includes(state.daemonState) && state.snapshot
      && state.snapshot.run && state.snapshot.run.id === run.id;
    if (!force && !active && this.last && this.last[0] === run.id) return; // an ended run
    try {
      const figures = await api("GET", `/runs/${run.id}/drift-removed`);
      if (!state.shownRun || state.shownRun.id !== run.id) return;
      this.last = [run.id, figures.steps];
      show(figures);
    } catch { /* no steps yet, or not readable: the headline keeps what it says */ }
  },
  refresh(run, state) {
    this.last = null;
    $("removed-figure").textContent = "";
    $("removed-text").textContent = `Run ${run.id}: waiting for its first measured step.`;
    this.poll(state, true);
  },
};

function show(figures) {
  const figure = $("removed-figure");
  const box = $("removed");
  let big = "";
  let tone = "neutral";
  if (figures.basis === "reference" && figures.removed_percent !== null) {
    if (figures.removed_percent >= 0 && !figures.headline.includes("noise")) {
      big = `${figures.removed_percent.toFixed(0)} %`;
      tone = figures.removed_percent >= 50 ? "good" : "poor";
    } else {
      tone = figures.headline.includes("noise") ? "neutral" : "bad";
    }
  } else if (figures.basis === "drift" && figures.residual_max_um !== null) {
    big = `${figures.residual_max_um.toFixed(1)} µm`;
  } else if (figures.residual_max_um !== null) {
    big = `${figures.residual_max_um.toFixed(1)} µm`;
  }
  figure.textContent = big;
  box.className = `removed ${tone}`;
  box.dataset.basis = figures.basis;
  let text = figures.headline;
  if (figures.rotation && figures.rotation.max_urad !== null) {
    const rotation = figures.rotation;
    const noise = rotation.noise_urad === null ? ""
      : ` (measurement 1σ ${rotation.noise_urad.toFixed(0)} µrad)`;
    text += ` Rotation error at most ${rotation.max_urad.toFixed(0)} µrad${noise}.`;
  }
  $("removed-text").textContent = text;
}
