// Helpers for live-view modules (a node package's ES module, served at /views/TYPE.js).
// A view module exports `mount(element, api)`; api gives:
//   api.node, api.data          the node's name and what its LiveView.data() returned
//   api.frame(values)           → Promise<{url, info}>: LiveView.frame(values) as an image
//   api.commit(values, save)    write LiveView.commit(values) into the graph (re-runs via the cache); with
//                               save (a file name in the graph's folder) then save the graph there;
//                               → Promise<{ok, errors, saved}>
//   api.exposure()              the page's preview exposure (stops)
// sliderView() builds the common case: sliders + a live image, committing on release.

export function sliderView(el, api, { sliders, note = '', live = true }) {
  const values = {};
  const wrap = document.createElement('div');
  const img = document.createElement('img');
  img.className = 'view-img';
  img.dataset.frames = '0';
  const info = document.createElement('div');
  info.className = 'dim view-info';
  if (note) { const p = document.createElement('div'); p.className = 'dim'; p.textContent = note; wrap.append(p); }
  let inflight = false, queued = false;
  async function update() {
    if (!live) return;
    if (inflight) { queued = true; return; }
    inflight = true;
    try {
      const { url, info: i } = await api.frame({ ...values });
      const old = img.src;
      img.src = url;
      img.dataset.frames = String(+img.dataset.frames + 1);
      if (old && old.startsWith('blob:')) URL.revokeObjectURL(old);
      info.textContent = i.error ? i.error : `${i.width}×${i.height}: ${i.compute_ms} ms compute, ${i.encode_ms} ms encode`;
    } finally {
      inflight = false;
      if (queued) { queued = false; update(); }
    }
  }
  for (const s of sliders) {
    values[s.key] = s.value;
    const row = document.createElement('div');
    row.className = 'ctl';
    row.title = s.description || '';
    const lab = document.createElement('label');
    lab.textContent = s.label || s.key;
    const f = document.createElement('div');
    f.className = 'field';
    const r = document.createElement('input');
    Object.assign(r, { type: 'range', min: s.min, max: s.max, step: s.step || (s.max - s.min) / 500, value: s.value });
    r.dataset.key = s.key;
    const out = document.createElement('output');
    out.textContent = (+s.value).toFixed(3);
    r.addEventListener('input', () => { values[s.key] = +r.value; out.textContent = (+r.value).toFixed(3); update(); });
    r.addEventListener('change', () => api.commit({ ...values }));
    f.append(r, out);
    row.append(lab, f);
    wrap.append(row);
  }
  wrap.append(img, info);
  el.append(wrap);
  update();
  return { values, img, update };
}
