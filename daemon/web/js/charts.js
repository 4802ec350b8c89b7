// Charts on uPlot (vendored, daemon/web/vendor/uplot-1.6.32): one helper per kind of plot,
// each sized to its container and resized with it.
import uPlot from "../vendor/uplot-1.6.32/uPlot.esm.js";

export const COLORS = { before: "#c2410c", after: "#1f5fae", trace: "#1f5fae", cost: "#6d28d9" };

const AXIS = { stroke: "#445468", grid: { stroke: "#edf0f4" }, ticks: { stroke: "#d9dee6" } };

function width(node) {
  return Math.max(280, Math.floor(node.clientWidth || node.parentElement.clientWidth || 600));
}

/** A uPlot in ``node`` (replacing what is there), resized with the node. */
function make(node, opts, data) {
  node.replaceChildren();
  const plot = new uPlot({ width: width(node), height: opts.height || 220, ...opts }, data, node);
  const ro = new ResizeObserver(() => {
    const w = width(node);
    if (Math.abs(w - plot.width) > 2) plot.setSize({ width: w, height: plot.height });
  });
  ro.observe(node);
  plot.cleanup = () => { ro.disconnect(); plot.destroy(); };
  return plot;
}

/** The live cable-length trace: x seconds before now, y length [mm]. */
export function traceChart(node) {
  return make(node, {
    height: 240,
    legend: { show: false },
    cursor: { show: false },
    scales: { x: { time: false, range: [-60, 0] } },
    axes: [
      { ...AXIS, label: "time before now [s]", values: (u, ticks) => ticks.map((t) => t.toFixed(0)) },
      { ...AXIS, label: "cable length [mm]", size: 70, values: linearTicks },
    ],
    series: [{}, { label: "length", stroke: COLORS.trace, width: 1.5, points: { show: false } }],
  }, [[], []]);
}

/** A line chart of ``ys`` against iteration (log y): the cost / convergence curve. */
export function costChart(node, height = 220) {
  return make(node, {
    height,
    legend: { show: false },
    cursor: { show: false },
    // Whole iterations on x: integer ticks only, the range widened to whole numbers.
    scales: { x: { time: false, range: (u, lo, hi) => [Math.floor(lo ?? 0), Math.max(Math.ceil(hi ?? 1), Math.floor(lo ?? 0) + 1)] }, y: { distr: 3 } },
    axes: [
      { ...AXIS, label: "iteration", incrs: [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000], values: (u, t) => t.map((v) => (Number.isInteger(v) ? String(v) : "")) },
      { ...AXIS, label: height < 200 ? "RMS [mm]" : "RMS residual [mm]", size: 70, values: (u, t) => t.map((v) => fmtTick(v)) },
    ],
    series: [{}, { label: "RMS [mm]", stroke: COLORS.cost, width: 2, points: { show: true, size: 4 } }],
  }, [[], []]);
}

/** Residual per sample: before and after as points against the sample number. */
export function residualChart(node, sampleNo, beforeMm, afterMm) {
  const series = [{ label: "sample" }];
  const data = [sampleNo];
  if (beforeMm) {
    series.push({ label: "before [mm]", stroke: COLORS.before, width: 0, points: { show: true, size: 5, fill: COLORS.before } });
    data.push(beforeMm);
  }
  series.push({ label: "after [mm]", stroke: COLORS.after, width: 0, points: { show: true, size: 5, fill: COLORS.after } });
  data.push(afterMm);
  return make(node, {
    height: 260,
    legend: { live: false },
    scales: { x: { time: false } },
    axes: [{ ...AXIS, label: "sample (in id order)" },
      { ...AXIS, label: "residual [mm]", size: 70, values: linearTicks }],
    series,
  }, data);
}

/** The measurement's drift term [mm] per sample (calib.drift), in sample order. */
export function driftChart(node, sampleNo, driftMm) {
  return make(node, {
    height: 200,
    legend: { show: false },
    cursor: { show: false },
    scales: { x: { time: false } },
    axes: [{ ...AXIS, label: "sample (in id order)" },
      { ...AXIS, label: "drift [mm]", size: 70, values: linearTicks }],
    series: [{}, { label: "drift [mm]", stroke: COLORS.cost, width: 2, points: { show: false } }],
  }, [sampleNo, driftMm]);
}

/** Histogram of before and after residuals on shared bins (bars side by side). */
export function histogramChart(node, beforeMm, afterMm) {
  const all = [...(beforeMm || []), ...afterMm].filter(Number.isFinite);
  const lim = Math.max(1e-6, ...all.map(Math.abs));
  const nBins = 21;
  const step = (2 * lim) / nBins;
  const centers = Array.from({ length: nBins }, (_, i) => -lim + step * (i + 0.5));
  const count = (xs) => {
    const c = new Array(nBins).fill(0);
    for (const x of xs) c[Math.min(nBins - 1, Math.max(0, Math.floor((x + lim) / step)))] += 1;
    return c;
  };
  const bars = uPlot.paths.bars;
  const series = [{ label: "residual [mm]" }];
  const data = [centers];
  if (beforeMm) {
    series.push({ label: "before", stroke: COLORS.before, fill: COLORS.before + "99", paths: bars({ size: [0.45], align: -1 }), points: { show: false } });
    data.push(count(beforeMm));
  }
  series.push({ label: "after", stroke: COLORS.after, fill: COLORS.after + "99", paths: bars({ size: [0.45], align: 1 }), points: { show: false } });
  data.push(count(afterMm));
  return make(node, {
    height: 260,
    legend: { live: false },
    cursor: { show: false },
    scales: { x: { time: false, range: [-lim - step, lim + step] } },
    axes: [{ ...AXIS, label: "residual [mm]", values: linearTicks },
      { ...AXIS, label: "samples", size: 50 }],
    series,
  }, data);
}

/** Tick labels of a linear axis with as many decimals as the tick spacing needs, so that no
 * two ticks read the same (a steady cable over 0.04 mm: 1034.02, 1034.03, … not 1034.0 four
 * times). */
export function linearTicks(u, ticks) {
  const step = ticks.length > 1 ? Math.abs(ticks[1] - ticks[0]) : 0;
  let digits = 0; // the decimals the spacing has (0.25 → 2, 2.5 → 1, 0.01 → 2)
  while (digits < 6 && step > 0 && Math.abs(step * 10 ** digits - Math.round(step * 10 ** digits)) > 1e-6 * step * 10 ** digits) digits += 1;
  return ticks.map((v) => (v == null ? "" : Math.abs(v) < step / 2 ? "0" : v.toFixed(digits)));
}

function fmtTick(v) {
  if (v == null) return "";
  const a = Math.abs(v);
  if (a === 0) return "0";
  if (a >= 100) return v.toFixed(0);
  if (a >= 1) return v.toFixed(1);
  if (a >= 0.001) return v.toPrecision(2);
  return v.toExponential(0);
}
