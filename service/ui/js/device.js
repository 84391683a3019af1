// A device: revision history per (sensor, kind), exports, pinned URLs, and the diff of two
// revisions (computed by the API: GET …/diff?from=&to=).

import { api, apiBlob } from './api.js';
import { h, fmt, age, enc, saveBlob, shortId } from './dom.js';
import { badge } from './quality.js';
import { renderDocument } from './result.js';

let kindsCache = null;

/** Job kinds (with their export formats), fetched once per page load. */
export async function jobKinds() {
  if (!kindsCache) kindsCache = await api('/v1/job-kinds');
  return kindsCache;
}

function docPath(serial, sensor, kind) {
  return `/v1/devices/${enc(serial)}/documents/${enc(sensor)}/${enc(kind)}`;
}

function exportButtons(serial, sensor, kind, rev, kinds) {
  const k = kinds.find((x) => x.name === kind);
  const formats = (k && k.exports) || [];
  return formats.map((f) => h('button', {
    type: 'button', class: 'ghost', dataset: { export: f.format },
    onclick: async () => {
      const blob = await apiBlob(`${docPath(serial, sensor, kind)}/${rev}?format=${enc(f.format)}`);
      saveBlob(blob, `${serial}_${sensor}_${kind}_r${rev}.${f.extension}`);
    },
  }, `Download ${f.format}`));
}

function pinButton(serial, sensor, kind, rev) {
  const url = new URL(`${docPath(serial, sensor, kind)}/${rev}`, location.href).href;
  const out = h('input', { type: 'text', readonly: true, value: url, 'aria-label': `Pinned URL of revision ${rev}`, hidden: true, size: 40 });
  const btn = h('button', {
    type: 'button', class: 'ghost', title: 'The URL of this exact revision: it never changes, unlike …/latest',
    onclick: async () => {
      out.hidden = false;
      out.select();
      try {
        await navigator.clipboard.writeText(url);
        btn.textContent = 'Pinned URL copied';
      } catch {
        btn.textContent = 'Pinned URL:';
      }
    },
  }, 'Pin');
  return h('span', {}, btn, ' ', out);
}

async function revisionCard(serial, doc, kinds) {
  const revs = await api(docPath(serial, doc.sensor, doc.kind));
  const options = revs.map((r) => h('option', { value: String(r.rev) }, `r${r.rev} · ${r.created_at}`));
  const from = h('select', { 'aria-label': 'Older revision', class: 'diff-from' }, options.map((o) => o.cloneNode(true)));
  const to = h('select', { 'aria-label': 'Newer revision', class: 'diff-to' }, options);
  if (revs.length > 1) from.value = String(revs[1].rev);
  const rows = revs.map((r) => h('tr', { dataset: { rev: String(r.rev) } },
    h('td', { class: 'num' }, h('a', { href: `#/devices/${enc(serial)}/${enc(doc.sensor)}/${enc(doc.kind)}/${r.rev}` }, `r${r.rev}`)),
    h('td', {}, h('time', { datetime: r.created_at, title: r.created_at }, age(r.created_at))),
    h('td', {}, badge(doc.kind, r.quality)),
    h('td', { class: 'hide-narrow' }, r.job ? h('a', { href: `#/jobs/${r.job}`, title: r.job }, 'job ' + shortId(r.job)) : '—',
      r.dataset ? h('div', { class: 'muted', title: r.dataset }, 'dataset ' + shortId(r.dataset)) : null,
      r.software ? h('div', { class: 'muted' }, r.software) : null),
    h('td', {}, pinButton(serial, doc.sensor, doc.kind, r.rev)),
  ));
  return h('article', { class: 'card', dataset: { sensor: doc.sensor, kind: doc.kind } },
    h('h2', {}, `${doc.sensor} · ${doc.kind}`),
    h('p', { class: 'muted' }, doc.schema),
    h('div', { class: 'actions' }, exportButtons(serial, doc.sensor, doc.kind, doc.latest_rev, kinds)),
    h('div', { class: 'table-wrap' }, h('table', { class: 'revisions' },
      h('thead', {}, h('tr', {}, ['Rev', 'Made', 'Quality', 'Made by', 'Pin'].map((t, i) => h('th', { scope: 'col', class: i === 3 ? 'hide-narrow' : null }, t)))),
      h('tbody', {}, rows))),
    revs.length > 1
      ? h('form', {
        class: 'toolbar diff-form',
        onsubmit: (e) => {
          e.preventDefault();
          location.hash = `#/devices/${enc(serial)}/${enc(doc.sensor)}/${enc(doc.kind)}/diff/${from.value}/${to.value}`;
        },
      }, h('span', {}, 'Compare '), from, h('span', {}, ' with '), to, h('button', { type: 'submit' }, 'Diff'))
      : null,
  );
}

export async function devicePage(serial) {
  const [docs, kinds] = await Promise.all([api(`/v1/devices/${enc(serial)}/documents`), jobKinds()]);
  const cards = await Promise.all(docs.documents.map((d) => revisionCard(serial, d, kinds)));
  const node = h('section', {},
    h('p', {}, h('a', { href: '#/fleet' }, '← Fleet')),
    h('h1', {}, 'Device ', h('code', {}, serial)),
    cards.length ? h('div', { class: 'stack' }, cards) : h('p', {}, 'This device has no documents.'),
  );
  return { node, title: serial };
}

export async function documentPage(serial, sensor, kind, rev) {
  const [doc, kinds] = await Promise.all([api(`${docPath(serial, sensor, kind)}/${rev}`), jobKinds()]);
  const prov = doc.provenance || {};
  const node = h('section', {},
    h('p', {}, h('a', { href: `#/devices/${enc(serial)}` }, `← ${serial}`)),
    h('h1', {}, `${sensor} · ${kind} · r${rev}`),
    h('dl', { class: 'kv' },
      h('dt', {}, 'Schema'), h('dd', {}, doc.schema),
      h('dt', {}, 'Made'), h('dd', {}, doc.created_at),
      h('dt', {}, 'Job'), h('dd', {}, prov.job ? h('a', { href: `#/jobs/${prov.job}` }, prov.job) : '—'),
      h('dt', {}, 'Dataset'), h('dd', {}, prov.dataset || '—'),
      h('dt', {}, 'Software'), h('dd', {}, prov.software ? `${prov.software.name} ${prov.software.version}` : '—'),
      h('dt', {}, 'ETag'), h('dd', {}, h('code', {}, doc.etag)),
    ),
    h('div', { class: 'actions' }, exportButtons(serial, sensor, kind, rev, kinds), pinButton(serial, sensor, kind, rev)),
    await renderDocument(doc),
  );
  return { node, title: `${serial} ${kind} r${rev}` };
}

export async function diffPage(serial, sensor, kind, a, b) {
  const d = await api(`${docPath(serial, sensor, kind)}/diff?from=${a}&to=${b}`);
  const onlyChanged = h('input', { type: 'checkbox', id: 'only-changed', checked: true });
  const tbody = h('tbody');
  const draw = () => {
    tbody.replaceChildren(...d.entries.filter((e) => !onlyChanged.checked || e.changed).map((e) => {
      const sig = e.delta_sigma;
      return h('tr', { class: e.changed ? 'diff-changed' : null },
        h('td', {}, h('code', {}, e.path)),
        h('td', { class: 'num' }, fmt(e.from)),
        h('td', { class: 'num' }, fmt(e.to)),
        h('td', { class: 'num' }, e.delta === undefined ? '' : fmt(e.delta)),
        h('td', { class: 'num' + (sig !== undefined && Math.abs(sig) > 3 ? ' sig-high' : '') },
          sig === undefined ? '' : `${fmt(sig, 3)} σ`));
    }));
  };
  onlyChanged.addEventListener('change', draw);
  draw();
  const node = h('section', {},
    h('p', {}, h('a', { href: `#/devices/${enc(serial)}` }, `← ${serial}`)),
    h('h1', {}, `${sensor} · ${kind}: r${a} → r${b}`),
    h('p', { id: 'diff-summary' }, `${d.changed} of ${d.entries.length} values differ. Δσ is the change over the combined standard deviation √(σ₁² + σ₂²); above 3 σ it is shown in red.`),
    h('p', {}, onlyChanged, h('label', { for: 'only-changed', class: 'inline' }, ' Only values that changed')),
    h('div', { class: 'table-wrap' }, h('table', { id: 'diff-table' },
      h('thead', {}, h('tr', {}, ['Value', `r${a}`, `r${b}`, 'Δ', 'Δσ'].map((t) => h('th', { scope: 'col' }, t)))),
      tbody)),
  );
  return { node, title: `diff r${a}–r${b}` };
}
