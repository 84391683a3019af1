// Run a calibration: upload a dataset (drag and drop or pick, with upload progress), choose a
// job kind, fill the form generated from its schema, submit, and follow the job live.

import { api, uploadDataset } from './api.js';
import { h, fmt } from './dom.js';
import { paramsForm } from './form.js';
import { jobKinds } from './device.js';

export async function runPage() {
  const kinds = await jobKinds();
  let dataset = null;

  const fileInput = h('input', { type: 'file', id: 'run-files', multiple: true });
  const bar = h('progress', { max: 100, value: 0, id: 'upload-progress', 'aria-label': 'Upload progress', hidden: true });
  const status = h('p', { id: 'upload-status', role: 'status' });
  const zone = h('div', { class: 'dropzone', id: 'dropzone' },
    h('p', {}, 'Drop images, a zip, an IMU log or a video here, or'),
    h('label', { for: 'run-files' }, 'Choose files'), fileInput, bar, status);

  const kindSel = h('select', { id: 'run-kind', required: true });
  const device = h('input', { id: 'run-device', type: 'text', placeholder: 'e.g. cam-0042', pattern: '[A-Za-z0-9._\\-]{1,128}' });
  const sensor = h('input', { id: 'run-sensor', type: 'text', placeholder: 'default', pattern: '[A-Za-z0-9._\\-]{1,128}' });
  const formHolder = h('div', { id: 'run-params' });
  const submit = h('button', { type: 'submit', id: 'run-submit', disabled: true }, 'Queue job');
  const message = h('p', { role: 'status', id: 'run-message' });
  let form = null;

  const fillKinds = () => {
    const fit = kinds.filter((k) => !dataset || k.dataset_kind === dataset.kind);
    const short = (d) => (d.length > 70 ? `${d.slice(0, 69)}…` : d);
    kindSel.replaceChildren(...fit.map((k) => h('option', { value: k.name, title: k.description }, `${k.name} — ${short(k.description)}`)));
    return showForm();
  };
  let shown = 0;
  const showForm = async () => {
    const k = kinds.find((x) => x.name === kindSel.value);
    if (!k) return;
    // Only the latest choice may fill the form, whichever schema load finishes last.
    const mine = ++shown;
    const f = await paramsForm(api, k);
    if (mine !== shown) return;
    form = f;
    formHolder.replaceChildren(h('h3', {}, 'Parameters'), form.node);
  };
  kindSel.addEventListener('change', () => showForm().catch((e) => { message.textContent = e.message; }));

  const upload = async (files) => {
    if (!files.length) return;
    bar.hidden = false;
    bar.value = 0;
    status.textContent = `Uploading ${files.length} file${files.length > 1 ? 's' : ''}…`;
    try {
      dataset = await uploadDataset(files, (sent, total) => {
        bar.value = total ? Math.round((100 * sent) / total) : 0;
      });
      bar.value = 100;
      status.textContent = `Dataset ${dataset.id}: ${dataset.kind}, ${dataset.file_count} file(s), ${fmt(dataset.total_bytes / 1e6, 3)} MB`;
      submit.disabled = false;
      await fillKinds();
      status.dataset.dataset = dataset.id;
    } catch (e) {
      status.textContent = `Upload refused: ${e.message}`;
      status.className = 'error-text';
    }
  };
  fileInput.addEventListener('change', () => upload([...fileInput.files]));
  zone.addEventListener('dragover', (e) => {
    e.preventDefault();
    zone.classList.add('over');
  });
  zone.addEventListener('dragleave', () => zone.classList.remove('over'));
  zone.addEventListener('drop', (e) => {
    e.preventDefault();
    zone.classList.remove('over');
    upload([...e.dataTransfer.files]);
  });

  const jobForm = h('form', {
    id: 'run-form',
    onsubmit: async (e) => {
      e.preventDefault();
      message.textContent = '';
      try {
        const body = { dataset: dataset.id, kind: kindSel.value, params: form ? form.read() : {} };
        if (device.value.trim()) body.device = device.value.trim();
        if (sensor.value.trim()) body.sensor = sensor.value.trim();
        const job = await api('/v1/jobs', { json: body });
        location.hash = `#/jobs/${job.id}`;
      } catch (err) {
        const field = err.problem && err.problem.field ? ` (field ${err.problem.field})` : '';
        message.textContent = `${err.message}${field}`;
        message.className = 'error-text';
      }
    },
  },
  h('label', { for: 'run-kind' }, 'Job kind'), kindSel,
  h('label', { for: 'run-device' }, 'Device serial (files the result as a versioned document)'), device,
  h('label', { for: 'run-sensor' }, 'Sensor'), sensor,
  formHolder,
  h('div', { class: 'actions' }, submit), message);

  await fillKinds();
  const node = h('section', {},
    h('h1', {}, 'Run a calibration'),
    h('h2', {}, '1. Dataset'), zone,
    h('h2', {}, '2. Job'), jobForm);
  return { node, title: 'Run' };
}
