// graphkit studio page: state over a websocket, DAG, controls, previews, live views.
import { Editor, backgroundText } from './graph.js';
import { mountPalette } from './palette.js';
import { makeControl, boundParam } from './controls.js';

const token = new URLSearchParams(location.search).get('token') || sessionStorage.getItem('gk-token') || '';
sessionStorage.setItem('gk-token', token);
if (location.search.includes('token=')) history.replaceState(null, '', location.pathname);

const $ = id => document.getElementById(id);
const studio = window.studio = {
  state: null, selected: null, preview: null, ws: null, events: 0, previewLoads: 0,
  previewDigest: null, lastError: null,
};

async function api(path, body) {
  const r = await fetch(path, {
    method: body === undefined ? 'GET' : 'POST',
    headers: { 'x-graphkit-token': token, 'content-type': 'application/json' },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  let data = null;
  try { data = await r.json(); } catch { data = { ok: false, error: `HTTP ${r.status}` }; }
  return data;
}

function log(msg) {
  const f = $('log');
  f.textContent = msg;
}

// ---- rendering ------------------------------------------------------------------------
const dag = studio.editor = new Editor($('graph'), {
  select: name => { if (studio.selected !== name) selectNode(name); },
  thumbURL: (node, port, max) => previewURL(node, port, max),
  open: (node, port) => setPreview([node, port]),
  edit: edits => edit(edits),
  undo: redo => undo(redo),
});
let controls = {};  // "node/param" or "/param" -> control

function nodeByName(name) { return (studio.state?.nodes || []).find(n => n.name === name); }

function render(state) {
  // states are sent from more than one thread: one older than the graph on show is stale
  if (studio.state && state.revision < studio.state.revision) return;
  studio.state = state;
  $('graph-name').textContent = state.graph.name;
  $('graph-path').textContent = $('graph-path').title = state.graph.path + (state.graph.dirty ? ' (edited, not saved)' : '');
  $('autorun').checked = state.autorun;
  showRun(state.run);
  dag.draw(state.nodes);
  const errs = $('errors');
  if (state.errors.length) {
    errs.hidden = false;
    errs.textContent = state.errors.map(e => e.text).join('\n');
  } else errs.hidden = true;
  const banner = $('banner');
  banner.hidden = !state.problems.length;
  banner.textContent = state.problems.map(p => 'warning: ' + p).join('\n');
  renderGraphParams(state);
  if (!studio.selected || !nodeByName(studio.selected)) {
    const first = state.preview ? state.preview[0] : (state.nodes[0] || {}).name;
    if (first) selectNode(first, true);
  } else renderNodePanel(nodeByName(studio.selected));
  renderPreviewChoices(state);
  refreshPreview();
}

function showRun(run) {
  // a run older than the one this page's last edit started is not shown: its "ok" would read
  // as the edit's result (set_params answers with the new run's number)
  if ((run?.gen ?? 0) < (studio.awaitGen ?? 0)) return;
  const el = $('run-status');
  const st = run?.status || 'idle';
  el.className = 'status ' + st;
  let t = st;
  if (st === 'ok') t = `ok ${run.seconds?.toFixed(2)}s · ${run.computed?.length ?? 0} computed, ${run.cached?.length ?? 0} cached`;
  if (st === 'failed') t = `failed: ${Object.keys(run.failed || {}).join(', ') || run.message}`;
  if (st === 'invalid') t = 'graph does not validate';
  el.textContent = el.title = t;
  el.dataset.gen = run?.gen ?? 0;
  el.dataset.status = st;
}

function renderGraphParams(state) {
  const box = $('gp-controls');
  const names = Object.keys(state.graph_params || {});
  const key = names.join(',') + '|' + JSON.stringify(Object.keys(state.graph_param_schema));
  if (box.dataset.key !== key) {
    box.replaceChildren();
    box.dataset.key = key;
    for (const k of names) {
      const sch = state.graph_param_schema[k];
      const schema = sch ? sch.schema : guessSchema(state.graph_params[k]);
      const c = makeControl(k, schema, state.graph_params[k], state.defs,
        v => change(null, k, v, c));
      if (sch) c.root.title = (c.root.title ? c.root.title + '\n' : '') + `used by ${sch.used_by}`;
      controls['/' + k] = c;
      box.append(c.root);
    }
  } else {
    for (const k of names) controls['/' + k]?.set(state.graph_params[k]);
  }
  $('graph-params').hidden = !names.length;
}

function guessSchema(v) {
  if (typeof v === 'boolean') return { type: 'boolean' };
  if (typeof v === 'number') return { type: 'number' };
  if (typeof v === 'string') return { type: 'string' };
  return {};
}

function selectNode(name, quiet) {
  studio.selected = name;
  dag.select(name);
  const n = nodeByName(name);
  renderNodePanel(n, true);
  if (!quiet) {
    const img = Object.entries(n?.outputs || {}).find(([, t]) => t === 'Image' || t === 'Mask');
    if (img) setPreview([name, img[0]]);
  }
  mountView(n);
}

function renderNodePanel(n, rebuild) {
  const box = $('node-panel');
  if (!n) { box.replaceChildren(); return; }
  const key = n.name + '|' + n.type + '|' + JSON.stringify(n.raw_params);
  if (rebuild || box.dataset.key !== key) {
    box.dataset.key = key;
    box.replaceChildren();
    const h = document.createElement('h3');
    // a sweep's instance shows its values; its params are the sweep node's, edited there
    h.textContent = n.base && n.base !== n.name ? `${n.base} · ${n.type} (instance ${n.name})` : `${n.name} · ${n.type}`;
    box.append(h);
    const msg = document.createElement('div');
    msg.className = 'node-msg';
    msg.id = 'node-msg';
    box.append(msg);
    const sch = studio.state.schemas[n.type];
    if (sch?.description) {
      const d = document.createElement('div');
      d.className = 'doc';
      d.textContent = sch.description;
      box.append(d);
    }
    const props = sch?.params?.properties || {};
    for (const k of Object.keys(props)) {
      const bound = boundParam((n.raw_params || {})[k]);
      const c = makeControl(k, props[k], (n.params || {})[k], studio.state.defs,
        v => change(n.base || n.name, k, v, c), { bound });
      controls[n.name + '/' + k] = c;
      box.append(c.root);
    }
    const thumbs = document.createElement('div');
    thumbs.className = 'thumbs';
    thumbs.id = 'thumbs';
    box.append(thumbs);
  } else {
    const props = studio.state.schemas[n.type]?.params?.properties || {};
    for (const k of Object.keys(props)) controls[n.name + '/' + k]?.set((n.params || {})[k]);
  }
  const msg = $('node-msg');
  if (msg) {
    const bad = n.state === 'failed' || n.state === 'blocked';
    msg.textContent = bad ? n.message : backgroundText(n);
    msg.classList.toggle('background', !bad);
  }
  renderThumbs(n);
}

function renderThumbs(n) {
  const box = $('thumbs');
  if (!box) return;
  box.replaceChildren();
  for (const [port, t] of Object.entries(n.outputs || {})) {
    if (t !== 'Image' && t !== 'Mask') continue;
    if (!digestOf(n.name, port)) continue;
    const fig = document.createElement('figure');
    const img = document.createElement('img');
    img.src = previewURL(n.name, port, 160);
    img.onerror = () => { img.style.visibility = 'hidden'; };
    const cap = document.createElement('figcaption');
    cap.textContent = port;
    fig.append(img, cap);
    fig.addEventListener('click', () => setPreview([n.name, port]));
    box.append(fig);
  }
}

function digestOf(node, port) {
  return nodeByName(node)?.digests?.[port] || '';
}

function previewURL(node, port, max = 0) {
  const e = $('exposure').value;
  const d = digestOf(node, port);
  return `/api/preview?node=${encodeURIComponent(node)}&port=${encodeURIComponent(port)}&exposure=${e}` +
    (max ? `&max=${max}` : '') + `&v=${d}`;
}

function renderPreviewChoices(state) {
  const sel = $('preview-select');
  const opts = [];
  for (const n of state.nodes) for (const [p, t] of Object.entries(n.outputs || {}))
    if (t === 'Image' || t === 'Mask') opts.push(`${n.name}.${p}`);
  const key = opts.join(',');
  if (sel.dataset.key !== key) {
    sel.dataset.key = key;
    sel.replaceChildren(...opts.map(o => { const e = document.createElement('option'); e.value = e.textContent = o; return e; }));
  }
  const cmp = $('compare-select');
  if (cmp.dataset.key !== key) {
    const keep = cmp.value;
    cmp.dataset.key = key;
    cmp.replaceChildren(...['', ...opts].map(o => { const e = document.createElement('option'); e.value = o; e.textContent = o || '—'; return e; }));
    cmp.value = opts.includes(keep) ? keep : '';
  }
  refreshCompare();
  if (!studio.preview && state.preview) studio.preview = state.preview;
  if (studio.preview) sel.value = studio.preview.join('.');
}

// A/B compare: output B drawn over the preview (same size), shown right of the divider
async function refreshCompare() {
  const v = $('compare-select').value, b = $('preview-b');
  $('compare-split').hidden = b.hidden = !v;
  if (!v) return;
  const i = v.lastIndexOf('.'), node = v.slice(0, i), port = v.slice(i + 1);
  if (!digestOf(node, port)) return;
  const url = previewURL(node, port);
  if (b.dataset.url === url) return;
  b.dataset.url = url;
  const r = await fetch(url, { headers: { 'x-graphkit-token': token } });
  if (!r.ok) return;
  const bm = await createImageBitmap(await r.blob());
  b.width = bm.width; b.height = bm.height;
  b.getContext('2d').drawImage(bm, 0, 0);
  bm.close();
  splitCompare();
}

function splitCompare() {
  $('preview-b').style.clipPath = `inset(0 0 0 ${$('compare-split').value}%)`;
}

function setPreview(p) {
  studio.preview = p;
  $('preview-select').value = p.join('.');
  refreshPreview();
}

// The preview is a canvas.  A preview on show that a run computed anew comes pushed over
// the websocket before the node's event: raw RGBA from a server on the loopback (put on the
// canvas as it is: nothing to decode), a PNG otherwise; the run waits, a moment at most, for
// the page's "shown" before it goes on.  Other previews are fetched (PNG) and decoded with
// createImageBitmap.  Only the newest request is drawn (a late fetch never hides a newer push).
let previewSeq = 0;

function drawPreview(p, d, draw) {
  const cv = $('preview');
  previewSeq += 1;
  const seq = previewSeq;
  return { seq, put: (w, h, fill) => {
    if (seq !== previewSeq) return false;
    if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
    fill(cv.getContext('2d', { willReadFrequently: true }));
    previewLoaded(p, d);
    return true;
  } };
}

function onPushedPreview(head, bytes) {
  const shown = () => studio.ws?.send(JSON.stringify({ type: 'shown', digest: head.digest }));
  const p = studio.preview, cv = $('preview');
  const n = nodeByName(head.node);
  if (!n || !p || p[0] !== head.node || p[1] !== head.port || head.max || +head.exposure !== +$('exposure').value) return shown();
  n.digests = { ...(n.digests || {}), [head.port]: head.digest };
  const url = previewURL(head.node, head.port);
  if (cv.dataset.url === url) return shown();
  cv.dataset.url = url;
  const job = drawPreview(p, head.digest);
  if (head.format === 'rgba') {
    job.put(head.width, head.height, ctx => ctx.putImageData(
      new ImageData(new Uint8ClampedArray(bytes.buffer, bytes.byteOffset, head.width * head.height * 4), head.width, head.height), 0, 0));
    // "shown" once the frame with it has been painted: the rest of the run (file writers,
    // sheet) then does not compete with that paint for the CPU
    // (a hidden tab paints no frames: it answers at once)
    return document.hidden ? shown() : requestAnimationFrame(() => setTimeout(shown, 0));
  }
  createImageBitmap(new Blob([bytes], { type: 'image/png' })).then(bm => {
    job.put(bm.width, bm.height, ctx => ctx.drawImage(bm, 0, 0));
    bm.close();
  }).catch(() => {}).finally(shown);
}

function previewLoaded(p, d) {
  const cv = $('preview');
  cv.dataset.digest = d;
  studio.previewLoads += 1;
  studio.previewDigest = d;
  studio.previewLoadedAt = performance.now();
  $('preview-info').textContent = `${p.join('.')} · ${cv.width}×${cv.height} · ${d.slice(0, 12)}`;
}

async function refreshPreview() {
  const p = studio.preview;
  const cv = $('preview');
  if (!p) return;
  const d = digestOf(p[0], p[1]);
  const url = previewURL(p[0], p[1]);
  if (!d) {
    previewSeq += 1;
    cv.width = cv.height = 0; cv.dataset.digest = ''; cv.dataset.url = '';
    $('preview-info').textContent = `${p.join('.')}: not computed yet`;
    return;
  }
  if (cv.dataset.url === url) return;
  cv.dataset.url = url;
  const job = drawPreview(p, d);
  try {
    const r = await fetch(url, { headers: { 'x-graphkit-token': token } });
    if (!r.ok) return;
    const bm = await createImageBitmap(await r.blob());
    job.put(bm.width, bm.height, ctx => ctx.drawImage(bm, 0, 0));
    bm.close();
  } catch { /* a preview that cannot be shown leaves the last one */ }
}

// ---- graph edits: the server applies them (the loader's checks) or says why not -----------
async function edit(edits) {
  const r = await api('/api/edit', { edits });
  showEditMsg(r.ok ? '' : (r.errors || []).map(e => e.text).join('\n') || r.error);
  return r;
}

async function undo(redo) {
  const r = await api(redo ? '/api/redo' : '/api/undo', {});
  showEditMsg(r.ok ? '' : (r.errors || []).map(e => e.text).join('\n'));
}

function showEditMsg(text) {
  const el = $('edit-msg');
  el.hidden = !text;
  el.textContent = text || '';
  if (text) log(text);
}

// ---- param edits --------------------------------------------------------------------------
// While a change is in flight, newer values wait; only the newest is sent next.
const pending = new Map();
let sending = false;

function change(node, param, value, ctl) {
  pending.set((node ?? '') + '/' + param, { node, param, value, ctl });
  pump();
}

async function pump() {
  if (sending || !pending.size) return;
  sending = true;
  const batch = [...pending.values()];
  pending.clear();
  try {
    const changes = batch.map(({ node, param, value }) => ({ node, param, value }));
    // over the websocket when it is open (no HTTP request per slider move), else POST
    const res = studio.ws?.readyState === WebSocket.OPEN ? await wsParams(changes) : await api('/api/params', { changes });
    for (const b of batch) b.ctl?.error('');
    if (!res.ok) {
      const text = (res.errors || []).map(e => e.text).join('\n') || res.error;
      studio.lastError = text;
      for (const b of batch) b.ctl?.error(text);
      log(text);
    } else studio.lastError = null;
    if (res.ok && res.gen) {  // the run this edit started: shown as running from now on
      studio.awaitGen = Math.max(studio.awaitGen ?? 0, res.gen);
      showRun({ status: 'running', gen: res.gen });
    }
  } finally {
    sending = false;
    if (pending.size) pump();
  }
}

let paramsId = 0;
const paramsWaiters = new Map();

function wsParams(changes) {
  const id = ++paramsId;
  return new Promise(resolve => {
    paramsWaiters.set(id, resolve);
    studio.ws.send(JSON.stringify({ type: 'params', id, changes }));
  });
}

// ---- live views ---------------------------------------------------------------------
let frameId = 0;
const frameWaiters = new Map();

async function mountView(n) {
  const panel = $('view-panel');
  panel.replaceChildren();
  panel.hidden = true;
  if (!n || !n.view) return;
  panel.hidden = false;
  const h = document.createElement('h3');
  h.textContent = `live view · ${n.view.title}`;
  const body = document.createElement('div');
  body.id = 'view-body';
  panel.append(h, body);
  const res = await api(`/api/view/${encodeURIComponent(n.name)}`);
  studio.pendingView = res.pending ? n.name : null;  // mounted again when a run finishes
  if (!res.ok) { body.textContent = res.error; return; }
  try {
    const mod = await import(`/views/${encodeURIComponent(n.type)}.js`);
    mod.mount(body, {
      node: n.name, data: res.data, exposure: () => +$('exposure').value,
      frame: values => sendFrame(n.name, values),
      commit: (values, save) => sendCommit(n.name, values, save),
      token,
    });
  } catch (e) { body.textContent = `the view failed: ${e}`; }
}

function sendFrame(node, values) {
  const id = ++frameId;
  return new Promise(resolve => {
    frameWaiters.set(id, resolve);
    studio.ws.send(JSON.stringify({ type: 'frame', node, values, id, exposure: +$('exposure').value }));
  });
}

// → Promise of the studio's answer ({ok, errors, saved}); save: a file name to save the graph to after
function sendCommit(node, values, save) {
  const id = ++frameId;
  return new Promise(resolve => {
    frameWaiters.set(id, resolve);
    studio.ws.send(JSON.stringify({ type: 'commit', node, values, id, save }));
  });
}

async function onBinary(buf) {
  const dv = new DataView(buf);
  const n = dv.getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  if (head.type === 'preview') return onPushedPreview(head, new Uint8Array(buf, 4 + n));
  const blob = new Blob([new Uint8Array(buf, 4 + n)], { type: 'image/png' });
  const w = frameWaiters.get(head.id);
  frameWaiters.delete(head.id);
  if (w) w({ url: URL.createObjectURL(blob), info: head });
}

// ---- websocket --------------------------------------------------------------------------
function connect() {
  const ws = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = 'arraybuffer';
  studio.ws = ws;
  ws.onmessage = ev => {
    if (typeof ev.data !== 'string') { studio.events += 1; return onBinary(ev.data); }
    const m = JSON.parse(ev.data);
    if (m.type === 'batch') m.events.forEach(onEvent); else onEvent(m);
  };
  ws.onclose = () => {
    $('run-status').textContent = 'disconnected';
    studio.awaitGen = 0;  // a restarted studio numbers its runs from 1 again
    for (const w of paramsWaiters.values()) w({ ok: false, error: 'disconnected' });
    paramsWaiters.clear();
    setTimeout(connect, 1000);
  };
}

function onEvent(m) {
    studio.events += 1;
    if (m.type === 'state') {
      render(m.state);
    } else if (m.type === 'node') {
      const n = nodeByName(m.name);
      if (n) {
        Object.assign(n, { state: m.state, seconds: m.seconds, message: m.message, progress: m.progress,
          background: m.background, background_message: m.background_message });
        if (m.digests) n.digests = m.digests;
        dag.update(n);
        if (studio.selected === m.name) renderNodePanel(n);
        if (studio.preview && studio.preview[0] === m.name) refreshPreview();
      }
    } else if (m.type === 'run') {
      showRun(m);
      if (studio.state) studio.state.run = m;
      if (m.status === 'ok' && studio.pendingView && studio.pendingView === studio.selected) {
        mountView(nodeByName(studio.pendingView));
      }
    } else if (m.type === 'frame') {
      const w = frameWaiters.get(m.id);
      frameWaiters.delete(m.id);
      if (w) w({ url: '', info: m });
    } else if (m.type === 'commit') {
      if (!m.ok) log((m.errors || []).map(e => e.text).join('\n'));
      const w = frameWaiters.get(m.id);
      frameWaiters.delete(m.id);
      if (w) w(m);
    } else if (m.type === 'params') {
      const w = paramsWaiters.get(m.id);
      paramsWaiters.delete(m.id);
      if (w) w(m);
    } else if (m.type === 'notice') log(m.message);
}

$('run-btn').addEventListener('click', async () => {
  const r = await api('/api/run', {});
  if (!r.ok) log(r.error);
});
$('stop-btn').addEventListener('click', () => api('/api/stop', {}));
$('fit-btn').addEventListener('click', () => dag.fit());
$('layout-btn').addEventListener('click', () => dag.layout());
$('undo-btn').addEventListener('click', () => undo(false));
$('redo-btn').addEventListener('click', () => undo(true));
$('dup-btn').addEventListener('click', () => dag.duplicate());
$('rename-btn').addEventListener('click', () => dag.rename());
$('delete-btn').addEventListener('click', () => dag.remove());
$('palette-search').addEventListener('focus', () => { $('palette').hidden = false; });
document.addEventListener('click', e => {
  if (!e.target.closest('#palette, #palette-search')) $('palette').hidden = true;
});
$('autorun').addEventListener('change', e => api('/api/autorun', { on: e.target.checked }));
$('save-btn').addEventListener('click', async () => {
  const suggestion = (studio.state?.graph.path || 'graph.yaml').replace(/\.ya?ml$/, '') + '_edited.yaml';
  const path = prompt('save the graph (with the current params) as:', suggestion.split('/').pop());
  if (!path) return;
  const r = await api('/api/save', { path });
  log(r.ok ? `saved ${r.path}` : r.error);
});
$('exposure').addEventListener('input', e => {
  $('exposure-val').textContent = (+e.target.value).toFixed(1);
  refreshPreview();
  refreshCompare();
});
$('one-to-one').addEventListener('change', e => $('preview-frame').classList.toggle('one-to-one', e.target.checked));
$('compare-select').addEventListener('change', refreshCompare);
$('compare-split').addEventListener('input', splitCompare);
$('preview-select').addEventListener('change', e => {
  const v = e.target.value, i = v.lastIndexOf('.');
  setPreview([v.slice(0, i), v.slice(i + 1)]);
});
connect();
// the palette (every node type's ports: the registry imports them all, which takes a while)
api('/api/nodes').then(rows => {
  dag.setCatalogue(rows);
  mountPalette($('palette-search'), $('palette'), rows, type => { $('palette').hidden = true; dag.add(type); });
  if (studio.state) dag.draw(studio.state.nodes);
});
