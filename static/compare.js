// Compare page: GET /api/compare?runs=&metric= and one chart, a mean line and a min-max band per group.
import { api, fmtNumber, toast } from "/static/app.js";
import { COLORS, LineChart } from "/static/charts.js";

const state = { runs: [], metric: "", metrics: {}, chart: null };

function groupRow(group, index) {
  const row = document.createElement("tr");
  row.dataset.group = group.label;
  const label = document.createElement("td");
  const swatch = document.createElement("span");
  swatch.className = "swatch";
  swatch.style.background = COLORS[index % COLORS.length];
  label.append(swatch, document.createTextNode(" " + group.label));
  const runs = document.createElement("td");
  group.run_ids.forEach((id, i) => {
    const link = document.createElement("a");
    link.href = `/runs/${id}`;
    link.textContent = `#${id}`;
    if (i) runs.append(document.createTextNode(", "));
    runs.append(link);
  });
  const last = group.points.length ? group.points[group.points.length - 1] : null;
  const mean = document.createElement("td");
  mean.className = "num";
  mean.textContent = last === null ? "–" : fmtNumber(last[1], 3);
  const seeds = document.createElement("td");
  seeds.className = "num";
  seeds.textContent = String(group.run_ids.length);
  row.append(label, runs, mean, seeds);
  return row;
}

async function load() {
  if (!state.runs.length) return; // none picked: the page says how to pick them
  const params = new URLSearchParams({ runs: state.runs.join(","), metric: state.metric });
  const data = await api("GET", "/api/compare?" + params);
  const element = document.getElementById("compare-chart");
  const percent = state.metric.endsWith("success_rate");
  state.chart = new LineChart(element, {
    title: state.metrics[state.metric],
    percent,
    yMin: percent ? 0 : undefined,
    yMax: percent ? 1 : undefined,
    series: data.groups.map((group, i) => ({
      name: group.label, label: group.label, color: COLORS[i % COLORS.length], band: true,
    })),
  });
  state.chart.add(Object.fromEntries(data.groups.map((group) => [group.label, group.points])));
  document.getElementById("compare-groups-body").replaceChildren(...data.groups.map(groupRow));
}

document.addEventListener("DOMContentLoaded", () => {
  Object.assign(state, JSON.parse(document.getElementById("compare-data").textContent));
  const select = document.getElementById("compare-metric");
  select.addEventListener("change", () => {
    state.metric = select.value;
    const url = new URL(window.location.href);
    url.searchParams.set("metric", state.metric);
    window.history.replaceState(null, "", url);
    load().catch((error) => toast(error.message, "error", 6000));
  });
  load().catch((error) => toast(error.message, "error", 6000));
});
