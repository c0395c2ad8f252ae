// What a run's steps draw, as its kind's view says (GET /kinds; daemon/run/kind.py KindView):
// which plots, their titles and x axis, and its series. "axes": the spot's measured error (and
// the reference run's measured uncompensated drift beside it), the predicted deformation and
// the commanded compensation per axis. "poses": the tool's 3-D drift and rotation error, one
// series per measured pose (poses share no series, so no line zig-zags between them), the
// predicted tool error and the commanded correction per pose. Both: the temperatures, grouped
// per link and joint when the view says so; time in the run's or the model's clock.
import { Chart } from "./charts.js";
import { $, naturally, norm, num, palette, parsed, scaled } from "./util.js";

// every plot slot of the page (index.html ``slot-*``); a kind's view says which it shows
const ALL_SLOTS = ["residual", "drift3d", "rotation", "predicted", "offset", "temperature"];
const XYZ = palette(3);
const REFERENCE_COLOUR = "#7a7a7a";
const POSE_COLOURS = palette(8);

// "turret.3+" -> "turret": an arm's nodes are named link.segment±; the thesis's two links
// number theirs (1..17), which stay one series each
function groupOf(node, grouped) {
  return grouped ? node.split(".")[0] : node;
}

export class RunPlots {
  constructor() {
    this.view = null;
    this.charts = {};
    this.compensation = null;
    this.timeScale = 1;
    this.poses = [];
    this.temperatureNames = null;
    this.grouped = false;
  }

  // view: the run's kind's view (null: none known yet, nothing is drawn); parameters: the
  // run's (compensation, time scale)
  reset(view, parameters = {}) {
    for (const chart of Object.values(this.charts)) chart.destroy();
    this.view = view;
    this.compensation = parameters.compensation || null;
    this.timeScale = Number(parameters.time_scale) || 1;
    this.poses = [];
    this.temperatureNames = null;
    this.charts = {};
    const plots = new Map(((view && view.plots) || []).map((plot) => [plot.slot, plot]));
    for (const slot of ALL_SLOTS) {
      const plot = plots.get(slot);
      $(`slot-${slot}`).hidden = !plot;
      if (!plot) continue;
      this.charts[slot] = new Chart(`plot-${slot}`, {
        xLabel: slot === "temperature" ? view.temperature_x_label : view.x_label,
        legendTitle: slot === "temperature" ? "legend: temperatures" : "legend",
      });
      let title = plot.title;
      if (this.compensation === "off" && plot.title_uncompensated) {
        title = plot.title_uncompensated;
      }
      // a run that measures no rotation says so rather than leave an empty plot to be read
      // as "no rotation error" (a UR followed by its joint temperatures: 3-D drift only)
      if (slot === "rotation" && !view.rotation_measured) title += ": not measured in this run";
      $(`title-${slot}`).textContent = title;
    }
    document.body.dataset.series = view ? view.series : "";
  }

  get perPose() {
    return Boolean(this.view) && this.view.series === "poses";
  }

  x(step) {
    if (this.view && this.view.time_axis === "model-hours") {
      const model = num(step.model_time_s);
      const run = num(step.scheduled_s);
      if (model !== null) return model / 3600;
      return run === null ? null : (run * this.timeScale) / 3600;
    }
    return num(step.scheduled_s);
  }

  poseColour(pose) {
    if (!this.poses.includes(pose)) this.poses.push(pose);
    return POSE_COLOURS[this.poses.indexOf(pose) % POSE_COLOURS.length];
  }

  addStep(step) {
    if (!this.view) return;
    const x = this.x(step);
    const c = this.charts;
    if (this.perPose) {
      const pose = step.arm_pose || "tool";
      const style = { colour: this.poseColour(pose), width: 2 };
      c.drift3d.add(pose, x, num(step.drift_3d_um), style);
      c.rotation.add(pose, x, num(step.rotation_error_urad), style);
      c.predicted.add(pose, x, norm(step.predicted_tx_um, step.predicted_ty_um,
        step.predicted_tz_um), style);
      const correction = norm(step.correction_tx_mm, step.correction_ty_mm, step.correction_tz_mm);
      c.offset.add(pose, x, correction === null ? null : correction * 1000, style);
    } else {
      const name = this.compensation === "off" ? "measured drift" : "compensated error";
      c.residual.add(name, x, num(step.residual_um), { colour: "#c62828", width: 2 });
      ["x", "y", "z"].forEach((axis, i) => {
        c.predicted.add(axis, x, num(step[`predicted_${axis}_um`]), { colour: XYZ[i] });
        c.offset.add(axis, x, scaled(step[`offset_${axis}_mm`], 1000), { colour: XYZ[i] });
      });
    }
    this.addTemperatures(step, x);
  }

  addTemperatures(step, x) {
    const model = parsed(step.model_temperatures_json);
    const ir = parsed(step.ir_json);
    if (!this.temperatureNames) {
      const nodes = Object.keys(model).sort(naturally);
      if (!nodes.length && !Object.keys(ir).length) return;
      this.grouped = this.view.group_temperatures || nodes.some((n) => n.includes("."));
      const groups = [...new Set(nodes.map((n) => groupOf(n, this.grouped)))];
      const regions = Object.keys(ir).sort(naturally);
      const names = [
        ...groups.map((g) => (this.grouped ? g : `node ${g}`)),
        ...regions.map((r) => `IR ${r}`),
      ];
      const colours = palette(names.length);
      names.forEach((name, i) => this.charts.temperature.ensure(name, name.startsWith("IR ")
        ? { colour: colours[i], width: 2.5 } : { colour: colours[i], dash: [6, 3] }));
      this.temperatureNames = names;
    }
    const sums = new Map();
    for (const [node, value] of Object.entries(model)) {
      const v = num(value);
      if (v === null) continue;
      const name = this.grouped ? groupOf(node, true) : `node ${node}`;
      const [sum, count] = sums.get(name) || [0, 0];
      sums.set(name, [sum + v, count + 1]);
    }
    for (const [name, [sum, count]] of sums) this.charts.temperature.add(name, x, sum / count);
    for (const [region, reading] of Object.entries(ir)) {
      if (reading) this.charts.temperature.add(`IR ${region}`, x, num(reading.mean_c));
    }
  }

  // the measured uncompensated reference run, drawn beside this run's error (dashed, grey for
  // the spot; each pose's own colour for a tool's poses)
  setReference(runId, steps) {
    if (!this.view) return;
    if (this.perPose) {
      const byPose = new Map();
      for (const step of steps) {
        const pose = step.arm_pose || "tool";
        if (!byPose.has(pose)) byPose.set(pose, { xs: [], drift: [], rotation: [] });
        const entry = byPose.get(pose);
        const x = this.x(step);
        const drift = num(step.drift_3d_um);
        if (x === null || drift === null) continue;
        entry.xs.push(x);
        entry.drift.push(drift);
        entry.rotation.push(num(step.rotation_error_urad));
      }
      for (const [pose, entry] of byPose) {
        const style = { colour: this.poseColour(pose), width: 1.5, dash: [5, 4] };
        const name = `${pose}: run ${runId} uncompensated`;
        this.charts.drift3d.replace(name, entry.xs, entry.drift, style);
        this.charts.rotation.replace(name, entry.xs, entry.rotation, style);
      }
      return;
    }
    const xs = [];
    const ys = [];
    for (const step of steps) {
      const x = num(step.scheduled_s);
      const y = num(step.residual_um);
      if (x !== null && y !== null) { xs.push(x); ys.push(y); }
    }
    this.charts.residual.replace(`run ${runId} uncompensated (measured drift)`, xs, ys,
      { colour: REFERENCE_COLOUR, width: 1.5, dash: [5, 4] });
  }

  render() {
    for (const chart of Object.values(this.charts)) chart.render();
  }

  resize() {
    for (const chart of Object.values(this.charts)) chart.resize();
  }
}
