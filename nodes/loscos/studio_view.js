// Studio live view of Relight: a slider per real light over the linear fast path; with virtual
// lights or boxes (§4.5), the room at the photograph's resolution with a handle over each virtual
// thing: drag a box over the floor or a table (each move is VirtualSession.move on the server).
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  const d = api.data;
  const view = sliderView(el, api, { sliders: d.sliders, note: d.note, live: d.fast });
  if (d.room) roomView(el, api, d.room);
  return view;
}

function roomView(el, api, room) {
  const wrap = document.createElement('div');
  wrap.className = 'room-view';
  wrap.style.position = 'relative';
  const scale = Math.max(1, Math.floor(Math.min(512, el.clientWidth || 512) / room.width));
  const size = { width: `${room.width * scale}px`, height: `${room.height * scale}px` };
  const img = document.createElement('canvas');  // the frame, one canvas pixel per photo pixel
  Object.assign(img, { width: room.width, height: room.height, className: 'room-img' });
  Object.assign(img.style, size, { imageRendering: 'pixelated', display: 'block' });
  img.dataset.frames = '0';
  const over = document.createElement('canvas');  // the handles, at the shown size
  Object.assign(over, { width: room.width * scale, height: room.height * scale, className: 'room-handles' });
  Object.assign(over.style, size, { position: 'absolute', left: '0', top: '0', cursor: 'grab', touchAction: 'none' });
  const info = document.createElement('div');
  info.className = 'dim room-info';
  wrap.append(img, over);
  el.append(wrap, info);
  let handles = room.handles, grab = null, inflight = false, queued = null;

  function drawHandles() {
    const g = over.getContext('2d');
    g.clearRect(0, 0, over.width, over.height);
    g.font = '12px sans-serif';
    for (const h of handles) {
      const [x0, y0, x1, y1] = h.box.map(v => v * scale);
      g.strokeStyle = grab && grab.name === h.name ? '#ffd400' : (h.kind === 'light' ? '#8cf' : '#fff');
      g.setLineDash(h.kind === 'light' ? [4, 3] : []);
      g.strokeRect(x0, y0, x1 - x0, y1 - y0);
      g.beginPath();
      g.arc(h.xy[0] * scale, h.xy[1] * scale, 5, 0, 2 * Math.PI);
      g.stroke();
      g.fillStyle = g.strokeStyle;
      g.fillText(h.name, x0, Math.max(12, y0 - 3));
    }
  }

  async function show(values) {
    if (inflight) { queued = values; return; }
    inflight = true;
    img.dataset.busy = '1';  // '0' once the frame of the latest values is drawn
    try {
      const { url, info: i } = await api.frame(values);
      if (i.error) { info.textContent = i.error; return; }
      const im = new Image();
      im.src = url;
      await im.decode();
      img.getContext('2d').drawImage(im, 0, 0);
      URL.revokeObjectURL(url);
      img.dataset.frames = String(+img.dataset.frames + 1);
      handles = i.handles || handles;
      drawHandles();
      info.textContent = `${i.width}×${i.height}: ${i.compute_ms} ms (${i.links_reevaluated ?? 0} links re-evaluated, ${i.iterations ?? 0} iterations)`;
    } finally {
      inflight = false;
      if (queued) { const v = queued; queued = null; show(v); } else img.dataset.busy = '0';
    }
  }

  const at = ev => { const r = over.getBoundingClientRect(); return [(ev.clientX - r.left) / scale, (ev.clientY - r.top) / scale]; };
  over.addEventListener('pointerdown', ev => {
    const [x, y] = at(ev);
    const h = handles.find(h => h.kind === 'object' && x >= h.box[0] - 2 && x <= h.box[2] + 2 && y >= h.box[1] - 2 && y <= h.box[3] + 2);
    if (!h) return;
    grab = { name: h.name, dx: h.xy[0] - x, dy: h.xy[1] - y };
    over.setPointerCapture(ev.pointerId);
    over.style.cursor = 'grabbing';
    drawHandles();
  });
  const drag = ev => { const [x, y] = at(ev); return { name: grab.name, x: x + grab.dx, y: y + grab.dy }; };
  over.addEventListener('pointermove', ev => { if (grab) show({ drag: drag(ev) }); });
  over.addEventListener('pointerup', ev => {
    if (!grab) return;
    const v = { drag: drag(ev) };
    grab = null;
    over.style.cursor = 'grab';
    drawHandles();
    api.commit(v);
  });
  drawHandles();
  show({});
}
