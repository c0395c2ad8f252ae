// A plot of named series over uPlot. Series are added as they appear (a new measured pose, the
// reference run) and may have x values of their own: the chart aligns them on the union of
// the x values, a series missing a value there being a gap its line spans. Plots are sized
// from the window, so they use a 1920 x 1080 screen as well as a 1366 x 768 one.
import { $, element } from "./util.js";

export const MAX_POINTS = 20000; // per series; older points are dropped from the live view
const LEGEND_INLINE = 6; // more series than this: the legend folds away (a <details>)

// Two rows of plots fill the window below the header and headline; never below 160 px.
export function plotHeight() {
  const top = $("plots") ? $("plots").getBoundingClientRect().top + window.scrollY : 200;
  const free = window.innerHeight - Math.min(top, window.innerHeight * 0.4) - 24;
  return Math.max(160, Math.floor(free / 2) - 78);
}

export class Chart {
  constructor(elementId, { xLabel = "run time (s)", legendTitle = "legend" } = {}) {
    this.element = $(elementId);
    this.xLabel = xLabel;
    this.legendTitle = legendTitle;
    this.series = []; // {name, stroke, width, dash, xs, ys}
    this.data = [[]];
    this.names = [];
    this.plot = null;
    this.structure = "";
    this.dirty = true;
  }

  ensure(name, style = {}) {
    let series = this.series.find((s) => s.name === name);
    if (!series) {
      series = { name, stroke: style.colour || "#1f6feb", width: style.width || 1.5,
        dash: style.dash, xs: [], ys: [] };
      this.series.push(series);
    }
    return series;
  }

  add(name, x, y, style) {
    if (x === null || x === undefined || y === null || y === undefined || Number.isNaN(y)) {
      if (style) this.ensure(name, style); // the series exists (its legend entry) before data
      return;
    }
    const series = this.ensure(name, style);
    const last = series.xs.length - 1;
    if (last >= 0 && series.xs[last] === x) series.ys[last] = y;
    else { series.xs.push(x); series.ys.push(y); }
    if (series.xs.length > MAX_POINTS) { series.xs.shift(); series.ys.shift(); }
    this.dirty = true;
  }

  // a whole series at once (the reference run's): replaces what it had
  replace(name, xs, ys, style) {
    const series = this.ensure(name, style);
    series.xs = xs.slice(-MAX_POINTS);
    series.ys = ys.slice(-MAX_POINTS);
    this.dirty = true;
  }

  recolour(colours) {
    this.series.forEach((s, i) => { if (colours[i]) s.stroke = colours[i]; });
    this.structure = "";
    this.dirty = true;
  }

  clear() {
    this.series = [];
    this.dirty = true;
  }

  aligned() {
    const all = new Set();
    for (const s of this.series) for (const x of s.xs) all.add(x);
    const xs = [...all].sort((a, b) => a - b);
    const index = new Map(xs.map((x, i) => [x, i]));
    const columns = this.series.map((s) => {
      const column = new Array(xs.length).fill(null);
      s.xs.forEach((x, i) => { column[index.get(x)] = s.ys[i]; });
      return column;
    });
    return [xs, ...columns];
  }

  render() {
    if (!this.dirty) return;
    this.dirty = false;
    this.data = this.aligned();
    this.names = this.series.map((s) => s.name);
    const structure = JSON.stringify([this.xLabel, this.series.map((s) => [s.name, s.stroke])]);
    if (this.plot && structure === this.structure) {
      this.plot.setData(this.data);
      return;
    }
    this.structure = structure;
    this.build();
  }

  build() {
    if (this.plot) this.plot.destroy();
    this.element.replaceChildren();
    const options = {
      width: Math.max(this.element.clientWidth, 280),
      height: plotHeight(),
      scales: { x: { time: false } },
      axes: [{ label: this.xLabel }, {}],
      legend: { live: false },
      series: [{}, ...this.series.map((s) => ({
        label: s.name, stroke: s.stroke, width: s.width, dash: s.dash, spanGaps: true,
      }))],
    };
    this.plot = new uPlot(options, this.data, this.element);
    const legend = this.element.querySelector(".u-legend");
    if (legend && this.series.length > LEGEND_INLINE) {
      // many series (model nodes): the legend folds away and the plot keeps its place
      const details = element("details", "legend");
      details.append(element("summary", "", `${this.legendTitle} (${this.series.length})`));
      legend.replaceWith(details);
      details.append(legend);
    }
  }

  resize() {
    if (this.plot) {
      this.plot.setSize({ width: Math.max(this.element.clientWidth, 280), height: plotHeight() });
    }
  }

  destroy() {
    if (this.plot) this.plot.destroy();
    this.plot = null;
    this.element.replaceChildren();
    this.series = [];
    this.data = [[]];
    this.names = [];
    this.structure = "";
  }
}
