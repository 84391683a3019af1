// Plots. Bar charts and residual vectors are drawn as SVG elements (one <rect> per bar, each
// focusable with its value as a tooltip); curves use the vendored uPlot (zoom by dragging,
// double-click to reset, values on hover).

import { h, s, fmt } from './dom.js';

/** Bars with a label each; `excluded[i]` greys a bar out. */
export function barChart({ labels, values, excluded = [], title, unit = '', threshold = null }) {
  const W = 720, H = 240, L = 48, B = 28, T = 10, R = 10;
  const max = Math.max(1e-12, ...values.filter(Number.isFinite), threshold || 0) * 1.1;
  const bw = (W - L - R) / Math.max(1, values.length);
  const y = (v) => T + (H - T - B) * (1 - v / max);
  const svg = s('svg', { viewBox: `0 0 ${W} ${H}`, role: 'img', 'aria-label': title });
  svg.append(s('line', { class: 'axis', x1: L, y1: H - B, x2: W - R, y2: H - B }));
  svg.append(s('line', { class: 'axis', x1: L, y1: T, x2: L, y2: H - B }));
  for (const f of [0, 0.5, 1]) {
    const v = (max / 1.1) * f;
    svg.append(s('text', { x: L - 4, y: y(v) + 4, 'text-anchor': 'end' }, fmt(v, 2)));
  }
  values.forEach((v, i) => {
    const val = Number.isFinite(v) ? v : 0;
    const rect = s('rect', {
      class: 'bar' + (excluded[i] ? ' excluded' : ''), x: L + i * bw + bw * 0.1, y: y(val),
      width: Math.max(1, bw * 0.8), height: Math.max(0, H - B - y(val)), tabindex: 0,
      'data-value': val,
    }, s('title', {}, `${labels[i]}: ${fmt(v, 4)}${unit}${excluded[i] ? ' (not used)' : ''}`));
    svg.append(rect);
  });
  if (threshold !== null) {
    svg.append(s('line', { x1: L, x2: W - R, y1: y(threshold), y2: y(threshold), stroke: '#b3261e', 'stroke-dasharray': '4 3' }));
  }
  if (values.length <= 30) {
    labels.forEach((l, i) => svg.append(s('text', { x: L + (i + 0.5) * bw, y: H - B + 14, 'text-anchor': 'middle' }, String(i + 1))));
  }
  return h('figure', { class: 'chart bar-chart', dataset: { bars: String(values.length) } },
    h('figcaption', {}, title), svg);
}

/** Residual vectors in the image, magnified so sub-pixel errors are visible. */
export function residualPlot({ width, height, residuals, scale = 50, title }) {
  const W = 720, H = Math.round(720 * height / Math.max(1, width));
  const k = W / width;
  const svg = s('svg', { viewBox: `0 0 ${W} ${H}`, role: 'img', 'aria-label': title });
  svg.append(s('rect', { x: 0, y: 0, width: W, height: H, fill: '#fafbfc', stroke: '#d0d7de' }));
  for (const r of residuals) {
    const [x, y] = r.observed || r.pixel || [NaN, NaN];
    const [dx, dy] = r.residual || [0, 0];
    if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
    const color = r.inlier === false ? '#b3261e' : '#0b57d0';
    svg.append(s('circle', { cx: x * k, cy: y * k, r: 1.5, fill: color, 'fill-opacity': 0.5 }));
    svg.append(s('line', { x1: x * k, y1: y * k, x2: (x + dx * scale) * k, y2: (y + dy * scale) * k, stroke: color, 'stroke-width': 1.2 }));
  }
  return h('figure', { class: 'chart' }, h('figcaption', {}, `${title} (vectors ×${scale})`), svg);
}

/**
 * Curves with uPlot. `series`: [{label, x: [], y: [], dash?}] on a shared or own x; log axes
 * when asked. Returns a figure; the plot is built once the figure is in the page.
 */
export function curveChart({ title, series, xLabel, yLabel, logX = false, logY = false }) {
  const fig = h('figure', { class: 'chart curve-chart', dataset: { series: String(series.length) } }, h('figcaption', {}, title));
  const holder = h('div');
  fig.append(holder);
  if (typeof window.uPlot !== 'function') {
    fig.append(h('p', { class: 'muted' }, 'Plot library not loaded.'));
    return fig;
  }
  // uPlot wants one x array: merge the x values of every series.
  const xs = [...new Set(series.flatMap((c) => c.x))].filter(Number.isFinite).sort((a, b) => a - b);
  const data = [xs, ...series.map((c) => {
    const m = new Map(c.x.map((x, i) => [x, c.y[i]]));
    return xs.map((x) => (m.has(x) && Number.isFinite(m.get(x)) ? m.get(x) : null));
  })];
  const colors = ['#0b57d0', '#b3261e', '#116329', '#7d4e00', '#6f42c1', '#0a7e8c', '#555f6b'];
  const opts = {
    width: 700, height: 320,
    scales: { x: { time: false, distr: logX ? 3 : 1 }, y: { distr: logY ? 3 : 1 } },
    axes: [{ label: xLabel }, { label: yLabel, size: 70 }],
    series: [{ label: xLabel, value: (u, v) => (v === null ? '—' : fmt(v)) },
      ...series.map((c, i) => ({ label: c.label, stroke: colors[i % colors.length], width: 1.5, dash: c.dash, spanGaps: true, value: (u, v) => (v === null ? '—' : fmt(v)) }))],
    cursor: { drag: { x: true, y: true } },
  };
  const build = () => {
    const w = Math.min(900, Math.max(280, fig.clientWidth || 700));
    opts.width = w;
    new window.uPlot(opts, data, holder);
  };
  // Build when attached (width known); observers are cheap and fire once.
  const obs = new MutationObserver(() => {
    if (document.contains(fig)) {
      obs.disconnect();
      build();
    }
  });
  obs.observe(document.body, { childList: true, subtree: true });
  return fig;
}
