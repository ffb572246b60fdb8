// Small SVG line charts (an ES module): new LineChart(element, {title, series: [{name, label, color}], yMin, yMax}).
import { el, fmtNumber, fmtPercent } from "/static/app.js";

/** The colours of a chart's lines, in order (the run page's series, the compare page's groups). */
export const COLORS = ["#2f6fdf", "#e07b00", "#1f9d55", "#8e44ad", "#d64545", "#0f9bb4"];
const SVG_NS = "http://www.w3.org/2000/svg";
const CHART_W = 520;
const CHART_H = 220;
const PAD = { left: 48, right: 14, top: 10, bottom: 28 };

function niceTicks(min, max, count) {
  if (min === max) {
    const pad = Math.abs(min) > 0 ? Math.abs(min) * 0.1 : 1;
    min -= pad;
    max += pad;
  }
  const span = max - min;
  const rough = span / count;
  const magnitude = Math.pow(10, Math.floor(Math.log10(rough)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * magnitude).find((s) => span / s <= count) || magnitude * 10;
  const start = Math.floor(min / step) * step;
  const end = Math.ceil(max / step) * step;
  const ticks = [];
  for (let v = start; v <= end + step / 2; v += step) ticks.push(Number(v.toPrecision(12)));
  return ticks;
}

function tickLabel(value, extra = 0) {
  const abs = Math.abs(value);
  const sign = value < 0 ? "\u2212" : ""; // a real minus sign
  if (abs >= 1e6) return sign + Number((abs / 1e6).toFixed((abs >= 1e7 ? 0 : 1) + extra)) + "M";
  if (abs >= 1e3) return sign + Number((abs / 1e3).toFixed((abs >= 1e4 ? 0 : 1) + extra)) + "k";
  if (abs !== 0 && abs < 0.01) return sign + abs.toExponential(extra);
  return sign + String(Number(abs.toPrecision(3 + extra)));
}

/** The step axis of a chart with one point: half the step either side, 0 to 2 at step 0 (it was 999 to 1.001k
 * for a point at step 1,000). */
function stepsAroundOne(step) {
  const pad = step !== 0 ? Math.abs(step) / 2 : 1;
  return [Math.max(0, step - pad), step + pad];
}

/** Labels for the ticks, with as many more digits as it takes for no two to read the same (10.5k was "11k"). */
function tickLabels(ticks, format = tickLabel) {
  let labels = ticks.map((t) => format(t, 0));
  for (let extra = 1; extra <= 4 && new Set(labels).size < labels.length; extra++) {
    labels = ticks.map((t) => format(t, extra));
  }
  return labels;
}

function percentLabel(value, extra = 0) {
  return Number((value * 100).toFixed(extra)) + "%";
}

export class LineChart {
  constructor(element, options) {
    this.element = element;
    this.options = options;
    this.data = {};
    element.classList.add("chart");
    this.legend = el("div", { class: "chart-legend" });
    const title = el("div", { class: "chart-title" }, options.title);
    element.replaceChildren(el("div", { class: "chart-head" }, title, this.legend));
    this.svg = document.createElementNS(SVG_NS, "svg");
    this.svg.setAttribute("viewBox", `0 0 ${CHART_W} ${CHART_H}`);
    this.svg.setAttribute("role", "img");
    this.svg.setAttribute("aria-label", options.title);
    element.appendChild(this.svg);
    this.render();
  }

  /** Merge new points ({name: [[step, value], ...]}); a point at an existing step replaces it. */
  add(series) {
    let changed = false;
    for (const spec of this.options.series) {
      const points = series[spec.name];
      if (!points || !points.length) continue;
      const existing = this.data[spec.name] || [];
      // a point is [step, value] or, for a series with a spread band, [step, mean, low, high, ...]
      const byStep = new Map(existing.map((p) => [p[0], p]));
      for (const point of points) byStep.set(point[0], point);
      this.data[spec.name] = [...byStep.values()].sort((a, b) => a[0] - b[0]);
      changed = true;
    }
    if (changed) this.render();
  }

  render() {
    const svg = this.svg;
    while (svg.firstChild) svg.removeChild(svg.firstChild);
    const series = this.options.series.map((spec) => ({ ...spec, points: this.data[spec.name] || [] }));
    const all = series.flatMap((s) => s.points);
    this.legend.replaceChildren(
      ...series.map((s) => {
        const last = s.points.length ? s.points[s.points.length - 1][1] : null;
        const shown = this.options.percent && last !== null ? fmtPercent(last) : fmtNumber(last, 3);
        const item = el("span", { "data-series": s.name }, s.label, el("b", {}, shown));
        item.style.setProperty("--swatch", s.color);
        return item;
      })
    );
    if (!all.length) {
      this.text(CHART_W / 2, CHART_H / 2, "no data yet", "middle", "no-data");
      return;
    }
    let xMin = Math.min(...all.map((p) => p[0]));
    let xMax = Math.max(...all.map((p) => p[0]));
    if (xMin === xMax) [xMin, xMax] = stepsAroundOne(xMin);
    let yMin = Math.min(...all.map((p) => Math.min(p[1], p.length > 3 ? p[2] : p[1])));
    let yMax = Math.max(...all.map((p) => Math.max(p[1], p.length > 3 ? p[3] : p[1])));
    if (this.options.yMin !== undefined) yMin = Math.min(yMin, this.options.yMin);
    if (this.options.yMax !== undefined) yMax = Math.max(yMax, this.options.yMax);
    const yTicks = niceTicks(yMin, yMax, 4);
    yMin = yTicks[0];
    yMax = yTicks[yTicks.length - 1];
    const xTicks = niceTicks(xMin, xMax, 5).filter((t) => t >= xMin && t <= xMax);
    const plotW = CHART_W - PAD.left - PAD.right;
    const plotH = CHART_H - PAD.top - PAD.bottom;
    const x = (v) => PAD.left + ((v - xMin) / (xMax - xMin)) * plotW;
    const y = (v) => PAD.top + (1 - (v - yMin) / (yMax - yMin || 1)) * plotH;

    const yLabels = tickLabels(yTicks, this.options.percent ? percentLabel : tickLabel);
    yTicks.forEach((t, i) => {
      this.line(PAD.left, y(t), CHART_W - PAD.right, y(t), "grid");
      this.text(PAD.left - 6, y(t) + 4, yLabels[i], "end", "tick y-tick");
    });
    const xLabels = tickLabels(xTicks);
    xTicks.forEach((t, i) => this.text(x(t), CHART_H - PAD.bottom + 16, xLabels[i], "middle", "tick x-tick"));
    this.line(PAD.left, PAD.top + plotH, CHART_W - PAD.right, PAD.top + plotH, "axis");
    this.text(CHART_W - PAD.right, CHART_H - 2, "env steps", "end");

    for (const s of series) {
      if (!s.band || s.points.length < 2) continue;
      const upper = s.points.map((p, i) => (i ? "L" : "M") + x(p[0]).toFixed(1) + " " + y(p[3]).toFixed(1));
      const lower = [...s.points].reverse().map((p) => "L" + x(p[0]).toFixed(1) + " " + y(p[2]).toFixed(1));
      const band = document.createElementNS(SVG_NS, "path");
      band.setAttribute("d", upper.join(" ") + " " + lower.join(" ") + " Z");
      band.setAttribute("class", "band");
      band.setAttribute("fill", s.color);
      band.setAttribute("fill-opacity", "0.15");
      band.setAttribute("data-series", s.name);
      svg.appendChild(band);
    }
    for (const s of series) {
      if (!s.points.length) continue;
      const d = s.points.map((p, i) => (i ? "L" : "M") + x(p[0]).toFixed(1) + " " + y(p[1]).toFixed(1)).join(" ");
      const path = document.createElementNS(SVG_NS, "path");
      path.setAttribute("d", d);
      path.setAttribute("class", "series");
      path.setAttribute("stroke", s.color);
      path.setAttribute("data-series", s.name);
      svg.appendChild(path);
      if (s.points.length <= 40) {
        for (const p of s.points) {
          const dot = document.createElementNS(SVG_NS, "circle");
          dot.setAttribute("cx", x(p[0]).toFixed(1));
          dot.setAttribute("cy", y(p[1]).toFixed(1));
          dot.setAttribute("r", "2.5");
          dot.setAttribute("fill", s.color);
          const title = document.createElementNS(SVG_NS, "title");
          title.textContent = `${s.label} at step ${p[0]}: ${fmtNumber(p[1], 4)}`;
          dot.appendChild(title);
          svg.appendChild(dot);
        }
      }
    }
  }

  line(x1, y1, x2, y2, cls) {
    const line = document.createElementNS(SVG_NS, "line");
    line.setAttribute("x1", x1);
    line.setAttribute("y1", y1);
    line.setAttribute("x2", x2);
    line.setAttribute("y2", y2);
    line.setAttribute("class", cls);
    this.svg.appendChild(line);
  }

  text(xPos, yPos, content, anchor, cls) {
    const text = document.createElementNS(SVG_NS, "text");
    text.setAttribute("x", xPos);
    text.setAttribute("y", yPos);
    text.setAttribute("text-anchor", anchor);
    if (cls) text.setAttribute("class", cls);
    text.textContent = content;
    this.svg.appendChild(text);
  }
}
