// Fleet: one page of devices at a time (GET /v1/devices), searchable by serial. The page
// never downloads the fleet: a 10,000-device fleet costs what 50 devices cost.

import { api } from './api.js';
import { h, age, enc } from './dom.js';
import { badge } from './quality.js';

const PAGE = 50;

export async function fleetPage(params) {
  const q = params.q || '';
  const cursor = params.cursor || '';
  const back = (params.back || '').split(',').filter(Boolean);
  const url = new URLSearchParams({ limit: String(PAGE) });
  if (q) url.set('q', q);
  if (cursor) url.set('cursor', cursor);
  const page = await api(`/v1/devices?${url}`);

  const search = h('input', { id: 'fleet-search', type: 'search', value: q, placeholder: 'serial contains…', autocomplete: 'off' });
  const form = h('form', {
    class: 'toolbar', role: 'search',
    onsubmit: (e) => {
      e.preventDefault();
      const v = search.value.trim();
      location.hash = '#/fleet' + (v ? '?' + new URLSearchParams({ q: v }) : '');
    },
  }, h('div', {}, h('label', { for: 'fleet-search' }, 'Search devices'), search), h('button', { type: 'submit' }, 'Search'));

  const rows = page.items.map((d) => h('tr', { dataset: { serial: d.serial } },
    h('td', {}, h('a', { href: `#/devices/${enc(d.serial)}` }, d.serial)),
    h('td', {}, h('div', { class: 'docs' }, d.documents.map((doc) => h('span', { class: 'doc-chip' },
      h('a', { href: `#/devices/${enc(d.serial)}/${enc(doc.sensor)}/${enc(doc.kind)}/${doc.latest_rev}` }, `${doc.sensor} · ${doc.kind}`),
      ' ', h('small', {}, `r${doc.latest_rev}, ${age(doc.created_at)}`), ' ', badge(doc.kind, doc.quality))))),
  ));

  const nav = h('div', { class: 'pager' });
  if (back.length || cursor) {
    const prev = back.slice(0, -1);
    const prevCursor = back.length ? back[back.length - 1] : '';
    const p = new URLSearchParams();
    if (q) p.set('q', q);
    if (prevCursor && prevCursor !== '-') p.set('cursor', prevCursor);
    if (prev.length) p.set('back', prev.join(','));
    nav.append(h('a', { class: 'button ghost', href: '#/fleet?' + p, rel: 'prev' }, '← Previous'));
  }
  if (page.next_cursor) {
    const p = new URLSearchParams({ cursor: page.next_cursor, back: [...back, cursor || '-'].join(',') });
    if (q) p.set('q', q);
    nav.append(h('a', { class: 'button', href: '#/fleet?' + p, rel: 'next', id: 'fleet-next' }, 'Next →'));
  }

  const node = h('section', { 'aria-labelledby': 'fleet-title' },
    h('h1', { id: 'fleet-title' }, 'Fleet'),
    form,
    h('p', { class: 'muted', id: 'fleet-count' }, `${page.total} device${page.total === 1 ? '' : 's'}${q ? ` matching “${q}”` : ''}`),
    page.items.length
      ? h('div', { class: 'table-wrap' }, h('table', { id: 'fleet-table' },
        h('caption', { class: 'muted' }, 'Latest document per sensor and kind'),
        h('thead', {}, h('tr', {}, h('th', { scope: 'col' }, 'Device'), h('th', { scope: 'col' }, 'Documents'))),
        h('tbody', {}, rows)))
      : h('p', {}, q ? 'No device matches.' : 'No device has a document yet. ', h('a', { href: '#/run' }, 'Run a calibration')),
    nav,
  );
  return { node, title: 'Fleet' };
}
