// Studio live view of ProbeLight (studio_view.py ProbeView): the mirror ball marked by hand.
// The probe photo is the preview of the node's `probe` input; the SVG over it has the image's
// own coordinates (viewBox 0 0 W H: pixel i spans [i, i+1], its centre at i + 0.5, as ProbeLight's),
// so the circle is drawn and dragged in the node's continuous pixel coordinates at any zoom.
// The flash direction comes from the server (ProbeView.frame: the node's own compute).
const SVG = 'http://www.w3.org/2000/svg';
const KEYS = ['centre_x', 'centre_y', 'radius'];
const HOW = {
  given: 'the circle given in the graph',
  found: 'the circle ProbeLight found',
  guess: 'a starting guess: drag the circle onto the ball\'s outline (centre and radius handles), or near it and ' +
         'press "Snap to outline", then apply',
  best: 'the circle ProbeLight found but was not sure of: check it against the ball\'s outline, press "Snap to ' +
        'outline" or drag it (centre and radius handles), then apply',
};

function node(tag, attrs = {}, ns = null) {
  const e = ns ? document.createElementNS(ns, tag) : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
}

export function mount(el, api) {
  const { width: W, height: H, probe } = api.data;
  const values = { ...api.data.circle };
  const root = node('div', { class: 'probe-view' });
  const status = node('div', { class: api.data.reason ? 'node-msg probe-reason' : 'dim' });
  status.textContent = api.data.reason ? `ProbeLight refused: ${api.data.reason}` : HOW[api.data.how];
  const hint = node('div', { class: 'dim' });
  if (api.data.reason) hint.textContent = HOW[api.data.how] || HOW.guess;

  // zoom and exposure of the photo
  const tools = node('div', { class: 'preview-head' });
  const zoom = node('select', { class: 'probe-zoom', title: 'screen pixels per probe pixel', style: 'flex:0' });
  for (const z of ['fit', '1', '2', '4', '8', '16']) zoom.append(new Option(z === 'fit' ? 'fit' : `${z}:1`, z));
  const expo = node('input', { type: 'number', step: '0.5', value: api.data.exposure, class: 'probe-exposure',
                               title: 'exposure of the photo (stops)' });
  tools.append('zoom ', zoom, ' exposure ', expo);

  const scroll = node('div', { class: 'probe-scroll', style: 'overflow:auto;max-height:60vh;background:#000' });
  const stage = node('div', { style: 'position:relative' });
  const img = node('img', { class: 'probe-photo', style: 'display:block;width:100%;image-rendering:pixelated' });
  const svg = node('svg', { viewBox: `0 0 ${W} ${H}`, preserveAspectRatio: 'none',
                            style: 'position:absolute;left:0;top:0;width:100%;height:100%;touch-action:none' }, SVG);
  const line = { 'vector-effect': 'non-scaling-stroke', fill: 'none' };
  const ball = node('circle', { ...line, stroke: '#30ff60', 'stroke-width': 1.5, class: 'probe-ball' }, SVG);
  const spoke = node('line', { ...line, stroke: '#30ff60', 'stroke-dasharray': '4 3' }, SVG);
  const hCentre = node('circle', { fill: '#30ff60', class: 'probe-handle-centre', style: 'cursor:move' }, SVG);
  const hRadius = node('circle', { fill: '#ffd030', class: 'probe-handle-radius', style: 'cursor:ew-resize' }, SVG);
  svg.append(ball, spoke, hCentre, hRadius);
  stage.append(img, svg);
  scroll.append(stage);

  // the three numbers
  const fields = {};
  const rows = KEYS.map(k => {
    const row = node('div', { class: 'ctl' });
    const lab = node('label');
    lab.textContent = `${k} (px)`;
    const f = node('input', { type: 'number', step: '0.01', 'data-key': k });
    f.addEventListener('input', () => { if (f.value !== '') { values[k] = +f.value; changed(false); } });
    fields[k] = f;
    row.append(lab, f);
    return row;
  });
  // snap: the outline fitted near the circle (ProbeView._snap), undone by "Undo"
  const snapRow = node('div', { class: 'preview-head' });
  const snapBtn = node('button', { class: 'probe-snap', style: 'white-space:nowrap',
                                   title: 'fit the ball\'s outline near this circle (a few pixels off is fine) ' +
                                          'and move the circle onto it' });
  snapBtn.textContent = 'Snap to outline';
  const undoBtn = node('button', { class: 'probe-undo', title: 'put back the circle as it was before the snap' });
  undoBtn.textContent = 'Undo';
  undoBtn.disabled = true;
  const snapNote = node('span', { class: 'dim probe-snapped' });
  snapRow.append(snapBtn, ' ', undoBtn, ' ', snapNote);
  const readout = node('div', { class: 'probe-readout', 'data-frames': '0' });
  const applyRow = node('div', { class: 'preview-head' });
  const file = node('input', { type: 'text', value: api.data.file, class: 'probe-file',
                               title: 'the graph file to write (in the graph\'s folder)' });
  const apply = node('button', { class: 'probe-apply', title: 'write centre_x, centre_y, radius into the graph and save it' });
  apply.textContent = 'Apply';
  const applied = node('span', { class: 'dim probe-applied' });
  applyRow.append(apply, ' to ', file, applied);
  root.append(status, hint, tools, scroll, ...rows, snapRow, readout, applyRow);
  el.append(root);

  function loadPhoto() {
    img.src = `/api/preview?node=${encodeURIComponent(probe.node)}&port=${encodeURIComponent(probe.port)}` +
      `&exposure=${+expo.value || 0}&max=0`;
  }
  function setZoom() { stage.style.width = zoom.value === 'fit' ? '100%' : `${W * +zoom.value}px`; draw(); }

  function draw() {
    const { centre_x: x, centre_y: y, radius: r } = values;
    const px = W / (svg.getBoundingClientRect().width || W);  // image units per screen pixel
    ball.setAttribute('cx', x); ball.setAttribute('cy', y); ball.setAttribute('r', Math.max(r, 0));
    spoke.setAttribute('x1', x); spoke.setAttribute('y1', y); spoke.setAttribute('x2', x + r); spoke.setAttribute('y2', y);
    for (const [h, hx] of [[hCentre, x], [hRadius, x + r]]) {
      h.setAttribute('cx', hx); h.setAttribute('cy', y); h.setAttribute('r', 5 * px);
    }
  }

  // a drag on a handle: the centre (kept at its offset from the pointer) or the radius
  function imagePoint(e) {
    const b = svg.getBoundingClientRect();
    return [(e.clientX - b.left) * W / b.width, (e.clientY - b.top) * H / b.height];
  }
  let drag = null;
  for (const [h, kind] of [[hCentre, 'centre'], [hRadius, 'radius']]) {
    h.addEventListener('pointerdown', e => {
      const [x, y] = imagePoint(e);
      drag = { kind, dx: values.centre_x - x, dy: values.centre_y - y };
      svg.setPointerCapture(e.pointerId);
      e.preventDefault();
    });
  }
  svg.addEventListener('pointermove', e => {
    if (!drag) return;
    const [x, y] = imagePoint(e);
    if (drag.kind === 'centre') Object.assign(values, { centre_x: x + drag.dx, centre_y: y + drag.dy });
    else values.radius = Math.hypot(x - values.centre_x, y - values.centre_y);
    changed(true);
  });
  svg.addEventListener('pointerup', () => { drag = null; });

  // the direction ProbeLight gives with this circle, asked again as it changes (one request at a time)
  let inflight = false, queued = false;
  async function update() {
    if (inflight) { queued = true; return; }
    inflight = true;
    try {
      const { url, info } = await api.frame({ ...values });
      if (url) URL.revokeObjectURL(url);
      readout.className = info.error ? 'node-msg probe-readout' : 'probe-readout';
      readout.textContent = info.error ? info.error :
        `flash direction (${info.frame} frame): (${info.direction.map(d => d.toFixed(4)).join(', ')})`;
      readout.dataset.frames = String(+readout.dataset.frames + 1);
    } finally {
      inflight = false;
      if (queued) { queued = false; update(); }
    }
  }
  function changed(toFields) {
    if (toFields) for (const k of KEYS) fields[k].value = values[k].toFixed(2);
    applied.textContent = '';
    draw();
    update();
  }

  let before = null;
  snapBtn.addEventListener('click', async () => {
    snapBtn.disabled = true;
    snapNote.className = 'dim probe-snapped';
    snapNote.textContent = ' snapping…';
    try {
      const was = { ...values };
      const { url, info } = await api.frame({ ...values, snap: true });
      if (url) URL.revokeObjectURL(url);
      const s = info.snap;
      if (info.error || !s || !s.circle) {
        snapNote.className = 'node-msg probe-snapped';
        snapNote.textContent = ` not snapped: ${info.error || (s && s.reason) || 'no outline near the circle'}`;
        return;
      }
      before = was;
      undoBtn.disabled = false;
      Object.assign(values, s.circle);
      snapNote.className = s.sure ? 'dim probe-snapped' : 'node-msg probe-snapped';
      snapNote.dataset.sure = String(s.sure);
      snapNote.textContent = s.sure ? ` snapped to the ball's outline: ${s.summary}; the direction within ` +
        `${s.doubt_deg.toFixed(2)}°` :
        ` snapped, not sure: ${s.reason} — compare the circle with the ball's outline at 4:1 or more, or undo`;
      changed(true);
    } catch (e) {
      snapNote.className = 'node-msg probe-snapped';
      snapNote.textContent = ` not snapped: ${e}`;
    } finally {
      snapBtn.disabled = false;
    }
  });
  undoBtn.addEventListener('click', () => {
    if (!before) return;
    Object.assign(values, before);
    before = null;
    undoBtn.disabled = true;
    snapNote.textContent = '';
    delete snapNote.dataset.sure;
    changed(true);
  });

  apply.addEventListener('click', async () => {
    applied.textContent = ' applying…';
    const r = await api.commit({ ...values }, file.value);
    applied.textContent = r.ok ? ` written to ${r.saved}` : ` not applied: ${(r.errors || []).map(e => e.text).join('; ')}`;
  });
  zoom.addEventListener('change', setZoom);
  // the handles keep their size on screen when the pane or the window is resized
  if (window.ResizeObserver) new ResizeObserver(() => draw()).observe(svg);
  expo.addEventListener('change', loadPhoto);
  img.addEventListener('load', draw);
  loadPhoto();
  setZoom();
  changed(true);
}
