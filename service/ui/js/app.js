// Shell of the dashboard: hash routes (so the server serves one page), the token dialog, and
// one error banner for anything that goes wrong (also recorded for the browser tests).

import { setToken, getToken } from './api.js';
import { mount, h } from './dom.js';
import { fleetPage } from './fleet.js';
import { devicePage, diffPage, documentPage } from './device.js';
import { jobsPage, jobPage } from './jobs.js';
import { runPage } from './run.js';

const view = document.getElementById('view');
const banner = document.getElementById('banner');
let cleanup = null;

/** Show an error to the user (and keep the page usable). */
export function showError(e) {
  const msg = e && e.message ? e.message : String(e);
  const code = e && e.code ? ` (${e.code})` : '';
  banner.textContent = msg + code;
  banner.hidden = false;
}

function clearError() {
  banner.hidden = true;
  banner.textContent = '';
}

const routes = [
  [/^#?\/?$/, () => fleetPage({})],
  [/^#\/fleet(?:\?(.*))?$/, (m) => fleetPage(Object.fromEntries(new URLSearchParams(m[1] || '')))],
  [/^#\/devices\/([^/]+)$/, (m) => devicePage(decodeURIComponent(m[1]))],
  [/^#\/devices\/([^/]+)\/([^/]+)\/([^/]+)\/diff\/(\d+)\/(\d+)$/,
    (m) => diffPage(...m.slice(1, 4).map(decodeURIComponent), +m[4], +m[5])],
  [/^#\/devices\/([^/]+)\/([^/]+)\/([^/]+)\/(\d+)$/,
    (m) => documentPage(...m.slice(1, 4).map(decodeURIComponent), +m[4])],
  [/^#\/jobs$/, () => jobsPage()],
  [/^#\/jobs\/([0-9a-fA-F-]{36})$/, (m) => jobPage(m[1])],
  [/^#\/run$/, () => runPage()],
];

async function route() {
  if (cleanup) {
    try {
      cleanup();
    } catch {
      /* a page's cleanup must not stop navigation */
    }
    cleanup = null;
  }
  clearError();
  const hash = location.hash || '#/fleet';
  const section = hash.split('/')[1] || 'fleet';
  for (const a of document.querySelectorAll('[data-nav]')) {
    if (a.dataset.nav === section.split('?')[0]) a.setAttribute('aria-current', 'page');
    else a.removeAttribute('aria-current');
  }
  const found = routes.find(([re]) => re.test(hash));
  if (!found) {
    mount(view, h('h1', {}, 'Not found'), h('p', {}, 'No page at ', hash, '. '), h('a', { href: '#/fleet' }, 'Go to the fleet'));
    return;
  }
  mount(view, h('p', { class: 'muted' }, 'Loading…'));
  try {
    const page = await found[1](hash.match(found[0]));
    mount(view, page.node);
    cleanup = page.cleanup || null;
    document.title = page.title ? `${page.title} · Caliper` : 'Caliper';
    // When each page had its data and was on screen (read by the browser tests).
    performance.mark(`caliper:page:${section.split('?')[0]}`);
    view.focus({ preventScroll: true });
  } catch (e) {
    mount(view, h('h1', {}, 'Something went wrong'), h('p', { class: 'error-text' }, e.message || String(e)));
    showError(e);
  }
}

function openTokenDialog() {
  const dlg = document.getElementById('token-dialog');
  const input = document.getElementById('token-input');
  input.value = getToken();
  dlg.showModal();
}

document.getElementById('token-button').addEventListener('click', openTokenDialog);
document.getElementById('token-dialog').addEventListener('close', (ev) => {
  const dlg = ev.target;
  if (dlg.returnValue === 'save') setToken(document.getElementById('token-input').value.trim());
  if (dlg.returnValue === 'clear') setToken('');
  if (dlg.returnValue) route();
});
document.addEventListener('caliper:unauthorized', () => {
  const dlg = document.getElementById('token-dialog');
  if (!dlg.open) openTokenDialog();
});
window.addEventListener('hashchange', route);
window.addEventListener('unhandledrejection', (ev) => showError(ev.reason));
window.addEventListener('error', (ev) => showError(ev.error || ev.message));
route();
