"""The HTML and JavaScript of the groom page (reports.view): plotly.js inlined, the strands' data as
JSON, and the code that builds one trace per state from it and handles picking.

The page's script publishes ``window.sagfreeView`` once plotted: ``pick(k)`` (returns whether k is
a strand), ``traces`` (name -> trace index: groomed, naive, optimized, failed, picked; bodies: a
list), ``strands`` (count) and ``ready`` (true). A page URL ending in ``#strand=K`` picks K on load.
"""
from __future__ import annotations

import json

STYLE = """
html, body { margin: 0; height: 100%; font-family: system-ui, sans-serif; font-size: 14px; }
body { display: flex; flex-direction: column; }
#bar { padding: 6px 10px; border-bottom: 1px solid #ddd; display: flex; gap: 8px; align-items: center;
       flex-wrap: wrap; }
#bar input { width: 6em; }
#info { color: #222; }
#plot { flex: 1 1 auto; min-height: 300px; }
"""

SCRIPT = r"""
(function () {
  "use strict";
  const D = JSON.parse(document.getElementById("sagfree-data").textContent);
  const N = D.counts.length, S = D.resolution;
  const gd = document.getElementById("plot"), info = document.getElementById("info");
  const input = document.getElementById("pick");

  // positions (m, flat x y z per vertex) of every strand in each state; null where not computed
  const groomed = [], naive = [], optimized = [], multiplier = [];
  let g = 0, a = 0, b = 0, m = 0;
  for (let k = 0; k < N; k++) {
    const n = D.counts[k], ints = new Float64Array(3 * n), P = new Float64Array(3 * n);
    for (let i = 0; i < 3 * n; i++) {
      ints[i] = D.groomed[g++] + (i >= 3 ? ints[i - 3] : 0);
      P[i] = ints[i] * S;
    }
    groomed.push(P);
    naive.push(D.hasNaive[k] ? shifted(ints, D.naive, a) : null);
    if (D.hasNaive[k]) a += 3 * n;
    optimized.push(D.hasOptimized[k] ? shifted(ints, D.optimized, b) : null);
    if (D.hasOptimized[k]) b += 3 * n;
    multiplier.push(D.hasOptimized[k] ? D.multiplier.slice(m, m + n) : null);
    if (D.hasOptimized[k]) m += n;
  }
  function shifted(ints, differences, start) {
    const out = new Float64Array(ints.length);
    for (let i = 0; i < ints.length; i++) out[i] = (ints[i] + differences[start + i]) * S;
    return out;
  }

  // one trace per state: strands one after another, a gap (null) between them
  const owner = [];  // per trace: the strand of each point (null at gaps)
  function lines(states, strands, colour) {
    const x = [], y = [], z = [], data = [], c = [], who = [];
    for (const k of strands) {
      const P = states[k], n = D.counts[k], w = multiplier[k];
      for (let i = 0; i < n; i++) {
        x.push(P[3 * i]); y.push(P[3 * i + 1]); z.push(P[3 * i + 2]);
        data.push([k, i, w ? w[i] : 1]); who.push(k);
        if (colour) c.push(Math.log10(Math.max(w[i], 1)));
      }
      x.push(null); y.push(null); z.push(null); data.push([k, -1, 1]); who.push(null);
      if (colour) c.push(0);
    }
    return {x: x, y: y, z: z, customdata: data, colour: c, owner: who};
  }
  const all = [...Array(N).keys()];
  const withNaive = all.filter(k => naive[k]), withOptimized = all.filter(k => optimized[k]);
  const failed = all.filter(k => !optimized[k] && D.counts[k] > 0);
  const where = "(%{x:.5f}, %{y:.5f}, %{z:.5f}) m";
  const traces = [], index = {};
  function add(name, built, line, template, extra) {
    index[name] = traces.length;
    owner.push(built.owner);
    traces.push(Object.assign({type: "scatter3d", mode: "lines", name: extra.label, x: built.x, y: built.y,
                               z: built.z, customdata: built.customdata, line: line, connectgaps: false,
                               hovertemplate: template + "<extra></extra>"}, extra.more || {}));
  }
  add("groomed", lines(groomed, all, false), {color: "#9a9a9a", width: 2},
      "groomed<br>strand %{customdata[0]}, vertex %{customdata[1]}<br>" + where,
      {label: "groomed (input shape)"});
  add("naive", lines(naive, withNaive, false), {color: "#ff7f0e", width: 2},
      "naive static droop (multiplier 1)<br>strand %{customdata[0]}, vertex %{customdata[1]}<br>" + where,
      {label: "naive static droop (p0)"});
  const top = Math.pow(10, D.logMax);  // the largest multiplier (at least 2): the colour bar's top tick
  const ticks = [1, 1.5, 2, 3, 5, 10, 20, 50, 100, 200, 500, 1000].filter(t => t < 0.9 * top).concat([top]);
  const built = lines(optimized, withOptimized, true);
  add("optimized", built, {color: built.colour, colorscale: "Viridis", cmin: 0, cmax: D.logMax, width: 4,
      showscale: true, colorbar: {title: {text: D.colourTitle, side: "right"}, len: 0.75,
      tickvals: ticks.map(Math.log10), ticktext: ticks.map(t => String(Number(t.toPrecision(3))))}},
      "optimized static state<br>strand %{customdata[0]}, vertex %{customdata[1]}<br>bend multiplier " +
      "%{customdata[2]:.3g}<br>" + where,
      {label: "optimized static state", more: {legendgroup: "optimized", showlegend: false}});
  // its legend entry: a plain-coloured stand-in of the same group (a legend line cannot take the
  // trace's colour array), one point (an empty trace gets no entry; a single point draws no line)
  const [x0, y0, z0] = built.x.length ? [built.x[0], built.y[0], built.z[0]] : [0, 0, 0];
  owner.push([null]);
  traces.push({type: "scatter3d", mode: "lines", name: "optimized static state (colour: multiplier)",
               x: [x0], y: [y0], z: [z0], line: {color: "#21918c", width: 4}, legendgroup: "optimized",
               hoverinfo: "skip"});
  if (failed.length) {
    add("failed", lines(groomed, failed, false), {color: "#d62728", width: 4},
        "NO PARAMETERS (groomed shape)<br>strand %{customdata[0]}, vertex %{customdata[1]}<br>" + where,
        {label: "no parameters: " + failed.length + " strand" + (failed.length > 1 ? "s" : "") +
                " (groomed shape)"});
  }
  add("picked", {x: [], y: [], z: [], customdata: [], owner: []}, {color: "#ff00ff", width: 9},
      "picked strand %{customdata[0]}, vertex %{customdata[1]}<br>" + where, {label: "picked strand"});
  index.bodies = [];
  for (const body of D.bodies) { index.bodies.push(traces.length); owner.push([]); traces.push(body); }

  // equal scales on the three axes (metres are metres), each axis spanning at least 5% of the widest
  // (a flat groom: plotly would stretch a zero span), the widest scaled to the default camera's view
  const low = [Infinity, Infinity, Infinity], high = [-Infinity, -Infinity, -Infinity];
  for (const t of traces) {
    [t.x, t.y, t.z].forEach((values, d) => {
      for (const v of values) if (v !== null) { if (v < low[d]) low[d] = v; if (v > high[d]) high[d] = v; }
    });
  }
  const span = [0, 1, 2].map(d => Math.max(high[d] - low[d], 0));
  const widest = Math.max(...span) || 1e-3;
  const ranges = [0, 1, 2].map(d => {
    const middle = isFinite(low[d]) ? (low[d] + high[d]) / 2 : 0, half = 0.52 * Math.max(span[d], 0.05 * widest);
    return [middle - half, middle + half];
  });
  const widestRange = Math.max(...ranges.map(r => r[1] - r[0]));
  const ratio = d => (ranges[d][1] - ranges[d][0]) / widestRange;
  const axis = (t, d) => ({title: {text: t}, range: ranges[d], showspikes: false});
  const layout = {
    title: {text: D.title + "<br><sub>" + D.subtitle + "</sub>"},
    showlegend: true, legend: {x: 0, y: 1, bgcolor: "rgba(255,255,255,0.75)"},
    margin: {l: 0, r: 0, t: 60, b: 0}, hovermode: "closest", uirevision: "keep",
    scene: {aspectmode: "manual", aspectratio: {x: ratio(0), y: ratio(1), z: ratio(2)},
            xaxis: axis("x (m)", 0), yaxis: axis("y (m)", 1), zaxis: axis("z (m)", 2)}
  };

  function format(value, digits) {
    return value === null ? "n/a" : value === 0 ? "0" : Number(value).toPrecision(digits);
  }
  function pick(k) {
    k = Number(k);
    if (!Number.isInteger(k) || k < 0 || k >= N) {
      info.textContent = "no strand " + k + ": the indices run from 0 to " + (N - 1);
      return false;
    }
    const P = optimized[k] || groomed[k], n = D.counts[k], x = [], y = [], z = [], data = [];
    for (let i = 0; i < n; i++) {
      x.push(P[3 * i]); y.push(P[3 * i + 1]); z.push(P[3 * i + 2]); data.push([k, i, 1]);
    }
    Plotly.restyle(gd, {x: [x], y: [y], z: [z], customdata: [data],
                        name: ["picked strand " + k + (optimized[k] ? "" : " (groomed shape)")]},
                   [index.picked]);
    owner[index.picked] = data.map(() => k);
    input.value = k;
    const note = D.note[k];
    info.innerHTML = "<b>strand " + k + "</b>: " + D.status[k] + "; " + n + " vertices; max bend multiplier " +
      format(D.maxMultiplier[k], 4) + "; static sag / L: naive " + format(D.naiveSag[k], 3) +
      ", optimized " + format(D.optimizedSag[k], 3) + (note ? "; " + note : "");
    return true;
  }
  document.getElementById("show").addEventListener("click", () => pick(input.value));
  input.addEventListener("keydown", e => { if (e.key === "Enter") pick(input.value); });

  Plotly.newPlot(gd, traces, layout, {responsive: true, displaylogo: false}).then(() => {
    gd.on("plotly_click", e => {
      const point = e && e.points && e.points[0];
      const who = point && owner[point.curveNumber] ? owner[point.curveNumber][point.pointNumber] : null;
      if (who !== null && who !== undefined) pick(who);
    });
    const hash = /strand=(\d+)/.exec(window.location.hash);
    if (hash) pick(hash[1]);
    window.sagfreeView = {pick: pick, traces: index, strands: N, ready: true};
  });
})();
"""


def page(data: dict) -> str:
    """The self-contained HTML page of reports.view's ``page_data``."""
    try:
        from plotly.offline import get_plotlyjs
    except ImportError:
        raise ImportError("sagfree view needs plotly (pip install plotly)") from None
    plotly_js = get_plotlyjs().replace("</script", "<\\/script")
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    count = len(data["counts"])
    last = max(count - 1, 0)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{data["title"]}</title>
<style>{STYLE}</style>
<script>{plotly_js}</script>
</head>
<body>
<div id="bar">
<label for="pick">strand</label>
<input id="pick" type="number" min="0" max="{last}" step="1" placeholder="0-{last}">
<button id="show">pick</button>
<span id="info">Type a strand index (0-{last}) or click a strand to pick it; click a legend entry to show or
hide a state.</span>
</div>
<div id="plot"></div>
<script type="application/json" id="sagfree-data">{payload}</script>
<script>{SCRIPT}</script>
</body>
</html>
"""

