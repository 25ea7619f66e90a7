// Controls generated from the JSON Schema that `graphkit schema` writes (pydantic's schema
// of each node's Params, where every value may also be a "${params.NAME}" string).
// Sliders for bounded numbers, colour pickers for RGB triples, menus for enums, text for
// strings and paths; the param's description is the tooltip.  Values are checked by the
// server (the graph loader), whose message is shown under the control.

// a param written as a reference: "${params.x}" (a graph param) or "${light.azimuth}" (a sweep's value)
const REF = /^\s*\$\{([A-Za-z_][A-Za-z0-9_]*)((?:\.[A-Za-z_][A-Za-z0-9_]*)*)\}\s*$/;

export function unwrap(s, defs) {
  if (!s || typeof s !== 'object') return {};
  let desc = s.description;
  if (Array.isArray(s.anyOf) && s.anyOf.length === 2 && (s.anyOf[1].pattern || '').startsWith('\\$\\{')) {
    s = s.anyOf[0];
  }
  if (s.$ref) {
    const name = s.$ref.split('/').pop();
    s = { ...(defs[name] || {}), ...s };
    delete s.$ref;
    return unwrap(s, defs);
  }
  let nullable = false;
  if (Array.isArray(s.anyOf)) {
    const rest = s.anyOf.filter(x => x.type !== 'null');
    nullable = rest.length < s.anyOf.length;
    if (rest.length === 1) s = { ...s, ...unwrap(rest[0], defs), anyOf: undefined };
  }
  return { ...s, description: desc || s.description || '', nullable: nullable || s.nullable };
}

const isColour = (name, s) => /colou?r|rgb|background/i.test(name + ' ' + (s.description || ''));

function lin2srgb(x) { x = Math.min(1, Math.max(0, x)); return x <= 0.0031308 ? 12.92 * x : 1.055 * x ** (1 / 2.4) - 0.055; }
function srgb2lin(x) { return x <= 0.04045 ? x / 12.92 : ((x + 0.055) / 1.055) ** 2.4; }
function hexOf(rgb) { return '#' + rgb.map(v => Math.round(lin2srgb(+v || 0) * 255).toString(16).padStart(2, '0')).join(''); }
function rgbOf(hex) { return [1, 3, 5].map(i => +srgb2lin(parseInt(hex.slice(i, i + 2), 16) / 255).toFixed(4)); }

function el(tag, attrs = {}, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v; else if (k in e && k !== 'list') e[k] = v; else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k);
  return e;
}

function bounds(s) {
  const lo = s.minimum ?? s.exclusiveMinimum, hi = s.maximum ?? s.exclusiveMaximum;
  return [lo, hi];
}

// A control: {root, set(value), active()}; onChange(value) is called on user edits
// (slider: while dragging, at most one in flight — the caller coalesces).
export function makeControl(name, schema, value, defs, onChange, opts = {}) {
  const s = unwrap(schema, defs);
  const root = el('div', { class: 'ctl', title: s.description || '' });
  root.dataset.param = name;
  const label = el('label', {}, name);
  const field = el('div', { class: 'field' });
  const err = el('div', { class: 'err' });
  root.append(label, field, err);
  let active = false;
  let set = () => {};
  const send = v => onChange(v);

  if (opts.bound) {
    const [owner, ...path] = opts.bound.split('.');
    const title = owner === 'params' ? `set by the graph param '${path.join('.')}'` : `set by the sweep '${owner}' (one value per instance)`;
    field.append(el('span', { class: 'bound', title }, `${JSON.stringify(value)}  ← \${${opts.bound}}`));
    set = v => { field.firstChild.textContent = `${JSON.stringify(v)}  ← \${${opts.bound}}`; };
  } else if (s.enum || s.const !== undefined) {
    const choices = s.enum || [s.const];
    const sel = el('select');
    for (const c of choices) sel.append(el('option', { value: JSON.stringify(c) }, String(c)));
    sel.addEventListener('change', () => send(JSON.parse(sel.value)));
    field.append(sel);
    set = v => { sel.value = JSON.stringify(v); };
  } else if (s.type === 'boolean') {
    const cb = el('input', { type: 'checkbox' });
    cb.addEventListener('change', () => send(cb.checked));
    field.append(cb);
    set = v => { cb.checked = !!v; };
  } else if (s.type === 'number' || s.type === 'integer') {
    const [lo, hi] = bounds(s);
    const step = s.type === 'integer' ? 1 : 'any';
    const num = el('input', { type: 'number', step });
    let range = null;
    if (lo !== undefined && hi !== undefined) {
      range = el('input', { type: 'range', min: lo, max: hi,
        step: s.type === 'integer' ? 1 : ((hi - lo) / 1000) });
      range.addEventListener('pointerdown', () => { active = true; });
      range.addEventListener('pointerup', () => { active = false; });
      range.addEventListener('input', () => {
        const v = s.type === 'integer' ? parseInt(range.value) : parseFloat(range.value);
        num.value = v; send(v);
      });
      range.addEventListener('change', () => { active = false; });
      field.append(range);
    }
    num.addEventListener('change', () => {
      if (num.value.trim() === '' && s.nullable) return send(null);
      const v = Number(num.value);
      if (range) range.value = v;
      send(Number.isFinite(v) ? (s.type === 'integer' && Number.isInteger(v) ? v : v) : num.value);
    });
    field.append(num);
    set = v => { num.value = v ?? ''; if (range && v !== null && v !== undefined) range.value = v; };
  } else if (s.type === 'array' && Array.isArray(s.prefixItems) && s.prefixItems.length === 3 &&
             s.prefixItems.every(x => unwrap(x, defs).type === 'number') && isColour(name, s)) {
    const pick = el('input', { type: 'color', title: 'colour (sRGB display of the linear RGB values)' });
    const nums = [0, 1, 2].map(() => el('input', { class: 'vec', type: 'number', step: 'any' }));
    const cur = () => nums.map(n => Number(n.value));
    pick.addEventListener('input', () => { const v = rgbOf(pick.value); nums.forEach((n, i) => { n.value = v[i]; }); send(v); });
    nums.forEach(n => n.addEventListener('change', () => { pick.value = hexOf(cur()); send(cur()); }));
    field.append(pick, ...nums);
    set = v => { if (Array.isArray(v)) { nums.forEach((n, i) => { n.value = v[i]; }); pick.value = hexOf(v); } };
  } else if (s.type === 'string' && !s.nullable) {
    const t = el('input', { type: 'text', spellcheck: false });
    t.addEventListener('change', () => send(t.value));
    field.append(t);
    set = v => { t.value = v ?? ''; };
  } else {
    // lists, mappings, optional values: edited as YAML/JSON flow text
    const t = el('input', { type: 'text', spellcheck: false, title: (s.description || '') + ' (JSON)' });
    t.addEventListener('change', () => {
      const txt = t.value.trim();
      if (txt === '' && s.nullable) return send(null);
      try { send(JSON.parse(txt)); } catch { send(txt); }
    });
    field.append(t);
    set = v => { t.value = v === undefined ? '' : JSON.stringify(v); };
  }
  set(value);
  return {
    root, name,
    set: v => { if (!active && !root.contains(document.activeElement)) set(v); },
    active: () => active,
    error: msg => { err.textContent = msg || ''; },
  };
}

// the reference a param is written as ("params.exposure", "light.azimuth"), or null
export function boundParam(raw) {
  const m = typeof raw === 'string' && raw.match(REF);
  return m ? m[1] + m[2] : null;
}
