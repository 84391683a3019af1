// A form generated from a job kind's JSON Schema (GET /v1/job-kinds, with `$ref`s resolved
// against /openapi.json). Empty fields are left out of the request so the server's defaults
// apply; anything the form cannot express (arrays, unions) is a JSON text field.

import { h } from './dom.js';

let components = null;

async function loadComponents(api) {
  if (!components) {
    const spec = await api('/openapi.json');
    components = (spec.components && spec.components.schemas) || {};
  }
  return components;
}

function resolve(schema, depth = 0) {
  if (!schema || depth > 8) return schema || {};
  if (schema.$ref) {
    const name = schema.$ref.split('/').pop();
    return resolve(components[name] || {}, depth + 1);
  }
  // Option<T> comes as oneOf [null, T] or type [T, "null"].
  const alts = schema.oneOf || schema.anyOf;
  if (alts) {
    const nonNull = alts.filter((a) => a.type !== 'null');
    if (nonNull.length === 1) return { ...resolve(nonNull[0], depth + 1), description: schema.description || nonNull[0].description };
  }
  if (Array.isArray(schema.type)) {
    const t = schema.type.filter((x) => x !== 'null');
    if (t.length === 1) return { ...schema, type: t[0] };
  }
  return schema;
}

let uid = 0;

/** Build the fields of `schema`; returns {node, read()} where read() gives the value or undefined. */
function field(name, raw, required, path) {
  const sc = resolve(raw);
  const id = `f${++uid}`;
  const desc = sc.description || raw.description;
  const label = h('label', { for: id }, name, required ? ' *' : '');
  const hint = desc ? h('p', { class: 'hint', id: `${id}-hint` }, desc) : null;
  const common = { id, name: path, 'aria-describedby': desc ? `${id}-hint` : null, required: required || null };
  if (sc.type === 'object' && sc.properties) {
    const inner = objectFields(sc, path);
    return {
      node: h('fieldset', {}, h('legend', {}, name, required ? ' *' : ''), hint, inner.node),
      read: () => {
        const v = inner.read();
        return Object.keys(v).length ? v : undefined;
      },
    };
  }
  if (Array.isArray(sc.enum)) {
    const sel = h('select', common, required ? null : h('option', { value: '' }, '(default)'),
      sc.enum.map((v) => h('option', { value: String(v) }, String(v))));
    if (sc.default !== undefined) sel.value = String(sc.default);
    return { node: h('div', {}, label, sel, hint), read: () => (sel.value === '' ? undefined : sel.value) };
  }
  if (sc.type === 'boolean') {
    const box = h('select', common, h('option', { value: '' }, '(default)'), h('option', { value: 'true' }, 'yes'), h('option', { value: 'false' }, 'no'));
    return { node: h('div', {}, label, box, hint), read: () => (box.value === '' ? undefined : box.value === 'true') };
  }
  if (sc.type === 'number' || sc.type === 'integer') {
    const input = h('input', { ...common, type: 'number', step: sc.type === 'integer' ? '1' : 'any', min: sc.minimum ?? null, max: sc.maximum ?? null, placeholder: sc.default !== undefined ? `default ${sc.default}` : '' });
    return { node: h('div', {}, label, input, hint), read: () => (input.value === '' ? undefined : Number(input.value)) };
  }
  if (sc.type === 'string') {
    const input = h('input', { ...common, type: 'text', placeholder: sc.default !== undefined ? `default ${sc.default}` : '' });
    return { node: h('div', {}, label, input, hint), read: () => (input.value === '' ? undefined : input.value) };
  }
  const area = h('textarea', { ...common, rows: 2, cols: 40, placeholder: 'JSON' });
  return {
    node: h('div', {}, label, area, hint),
    read: () => {
      if (area.value.trim() === '') return undefined;
      try {
        return JSON.parse(area.value);
      } catch {
        throw new Error(`${path}: not valid JSON`);
      }
    },
  };
}

function objectFields(sc, prefix) {
  const req = new Set(sc.required || []);
  const fields = Object.entries(sc.properties || {}).map(([k, v]) => [k, field(k, v, req.has(k), prefix ? `${prefix}.${k}` : k)]);
  return {
    node: h('div', { class: 'fields' }, fields.map(([, f]) => f.node)),
    read: () => {
      const out = {};
      for (const [k, f] of fields) {
        const v = f.read();
        if (v !== undefined) out[k] = v;
      }
      return out;
    },
  };
}

/** The parameter form of a kind. */
export async function paramsForm(api, kind) {
  await loadComponents(api);
  const sc = resolve(kind.params_schema);
  return objectFields(sc, '');
}
