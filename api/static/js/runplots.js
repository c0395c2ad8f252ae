// What a run's steps draw, by run kind. A two-link run: its measured error (and the reference
// run's measured uncompensated drift beside it), the predicted deformation, the commanded
// compensation, the temperatures. An arm run: the tool's 3-D drift and rotation error at the
// top, one series per measured pose (poses share no series, so no line zig-zags between
// them), the predicted tool error and the commanded correction per pose, and the temperatures
// grouped per link and joint; time in hours of the arm's warm-up.
import { Chart } from "./charts.js";
import { $, naturally, norm, num, palette, parsed, scaled } from "./util.js";

const SLOTS = {
  "two-link": ["residual", "predicted", "offset", "temperature"],
  arm: ["drift3d", "rotation", "predicted", "offset", "temperature"],
};
const TITLES = {
  "two-link": {
    residual: "Measured error of the tool, compensated (µm)",
    predicted: "Predicted deformation (µm)",
    offset: "Commanded compensation (µm)",
    temperature: "Temperatures (°C): model nodes dashed, IR regions solid",
  },
  arm: {
    drift3d: "3-D drift of the tool per measured pose (µm)",
    rotation: "Rotation error of the tool per measured pose (µrad)",
    predicted: "Predicted tool error |translation| per pose (µm)",
    offset: "Commanded correction |translation| per pose (µm)",
    temperature: "Temperatures (°C): mean per link and joint (model, dashed), IR regions solid",
  },
};
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
    this.kind = null;
    this.charts = {};
    this.compensation = null;
    this.timeScale = 1;
    this.poses = [];
    this.temperatureNames = null;
    this.grouped = false;
    this.rotationSeen = false;
    this.driftSeen = false;
  }

  // kind: "two-link" | "arm"; run: the run's parameters (compensation, time scale)
  reset(kind, parameters = {}) {
    for (const chart of Object.values(this.charts)) chart.destroy();
    this.kind = kind;
    this.compensation = parameters.compensation || null;
    this.timeScale = Number(parameters.time_scale) || 1;
    this.poses = [];
    this.temperatureNames = null;
    this.rotationSeen = false;
    this.driftSeen = false;
    const xLabel = kind === "arm" ? "arm time (h)" : "run time (s)";
    this.charts = {};
    for (const slot of ["residual", "drift3d", "rotation", "predicted", "offset", "temperature"]) {
      const shown = SLOTS[kind].includes(slot);
      $(`slot-${slot}`).hidden = !shown;
      if (!shown) continue;
      this.charts[slot] = new Chart(`plot-${slot}`, {
        xLabel: slot === "temperature" && kind !== "arm" ? "run time (s)" : xLabel,
        legendTitle: slot === "temperature" ? "legend: temperatures" : "legend",
      });
      $(`title-${slot}`).textContent = TITLES[kind][slot];
    }
    if (kind === "two-link" && this.compensation === "off") {
      $("title-residual").textContent = "Measured drift of the tool, compensation off (µm)";
    }
    document.body.dataset.kind = kind;
  }

  x(step) {
    if (this.kind === "arm") {
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
    const x = this.x(step);
    const c = this.charts;
    if (this.kind === "arm") {
      const pose = step.arm_pose || "tool";
      const style = { colour: this.poseColour(pose), width: 2 };
      c.drift3d.add(pose, x, num(step.drift_3d_um), style);
      c.rotation.add(pose, x, num(step.rotation_error_urad), style);
      this.noteRotation(step);
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
    this.addTemperatures(step, this.kind === "arm" ? x : num(step.scheduled_s));
  }

  addTemperatures(step, x) {
    const model = parsed(step.model_temperatures_json);
    const ir = parsed(step.ir_json);
    if (!this.temperatureNames) {
      const nodes = Object.keys(model).sort(naturally);
      if (!nodes.length && !Object.keys(ir).length) return;
      this.grouped = this.kind === "arm" || nodes.some((n) => n.includes("."));
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

  // A run that measures the tool's position but never its rotation (a UR followed by its
  // joint temperatures: the bench's truth gives the 3-D drift only) says so in the rotation
  // plot's title rather than leaving an empty plot to be read as "no rotation error".
  noteRotation(step) {
    if (this.rotationSeen) return;
    if (num(step.rotation_error_urad) !== null) {
      this.rotationSeen = true;
      $("title-rotation").textContent = TITLES.arm.rotation;
    } else if (!this.driftSeen && num(step.drift_3d_um) !== null) {
      this.driftSeen = true;
      $("title-rotation").textContent = `${TITLES.arm.rotation}: not measured in this run`;
    }
  }

  // the measured uncompensated reference run, drawn beside this run's error (dashed, grey on a
  // two-link run; each pose's own colour on an arm run)
  setReference(runId, steps) {
    if (this.kind === "arm") {
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
