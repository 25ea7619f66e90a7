// The graph pane: a litegraph canvas (vendor/litegraph-*, the node editor ComfyUI is built on)
// laid out by ELK's layered algorithm (vendor/elkjs-*: layers left to right, port order kept).
//
// The canvas mirrors the server's graph and never changes it on its own: an edit (add,
// connect, disconnect, delete, rename, duplicate) goes to /api/edit, which applies it to the
// YAML text and runs the loader's checks; the new state comes back over the websocket and is
// drawn.  A link the loader refuses is never drawn; its message is shown (onRefused).

const LG = window.litegraph.js;
const { LGraph, LGraphCanvas, LGraphNode, LiteGraph } = LG;

const TYPE_COLOURS = { Image: '#5aa9e6', Mask: '#c0c0c0', Mesh: '#f0a050', Camera: '#b070d0',
  Light: '#f0e060', File: '#8aa0b0', Scene: '#60c0a0' };
export function typeColour(t) {
  if (TYPE_COLOURS[t]) return TYPE_COLOURS[t];
  let h = 0;
  for (const c of String(t)) h = (h * 31 + c.charCodeAt(0)) % 360;
  return `hsl(${h},55%,62%)`;
}
const STATE_COLOURS = { idle: '#5a606c', queued: '#5a606c', cached: '#3aa0c8', running: '#e0b030',
  done: '#4cb860', failed: '#e05050', blocked: '#8a6a3a' };
const W = 210, INFO = 34, THUMB = 84;
// Below this zoom litegraph draws nodes without text; the editor then writes each node's name
// at a fixed size on screen (LABEL_PX) wherever it fits in the node's box.
const FAR = 0.6, LABEL_PX = 12;

// ELK lays out in a Web Worker (elk_worker.js), so a big graph's layout never blocks the page.
// Started with the page, so ELK loads while the page does.
const worker = new Worker('/static/elk_worker.js');
const waiting = new Map();
let asked = 0;
worker.onmessage = ({ data }) => {
  const w = waiting.get(data.id);
  waiting.delete(data.id);
  if (data.error) w.reject(new Error(data.error)); else w.resolve(data.graph);
};
function layOut(graph) {
  const id = ++asked;
  return new Promise((resolve, reject) => { waiting.set(id, { resolve, reject }); worker.postMessage({ id, graph }); });
}

LiteGraph.isValidConnection = () => true;  // the engine decides (onConnectInput → /api/edit)
LiteGraph.release_link_on_empty_shows_menu = false;
LGraphCanvas.prototype.processContextMenu = () => {};  // no local menus that change the graph

// A sweep's instances ("lamp[ring00]", …) are drawn as one node, "lamp ×32", whose state is
// the most telling of theirs; the YAML has one node for them, which the edits address.
const SWEPT = /^(.+)\[([^\]]+)\]$/;
const RANK = ['failed', 'running', 'blocked', 'queued', 'idle', 'done', 'cached'];
const base = name => (SWEPT.exec(name) || [, name])[1];

function collapse(nodes) {
  const out = new Map();
  for (const n of nodes) {
    const name = base(n.name);
    let g = out.get(name);
    if (!g) out.set(name, g = { ...n, name, inputs: [], members: [] });
    g.members.push(n);
    for (const [p, src, sp] of n.inputs) {
      const b = base(src);
      if (!g.inputs.some(x => x[0] === p && x[1] === b && x[2] === sp)) g.inputs.push([p, b, sp]);
    }
  }
  for (const g of out.values()) {
    if (g.members.length < 2 && g.members[0].name === g.name) {  // not swept: one link per sweep it reads
      out.set(g.name, g.inputs.length === g.members[0].inputs.length ? g.members[0] : { ...g.members[0], inputs: g.inputs });
      continue;
    }
    g.count = g.members.length;
    const worst = g.members.reduce((a, m) => RANK.indexOf(m.state || 'idle') < RANK.indexOf(a.state || 'idle') ? m : a);
    g.state = worst.state; g.message = worst.message; g.progress = undefined;
    g.seconds = g.members.every(m => m.seconds != null) ? g.members.reduce((t, m) => t + m.seconds, 0) : null;
    g.done = g.members.filter(m => m.state === 'done' || m.state === 'cached').length;
  }
  return [...out.values()];
}

// what a node does in the background after its run (Context.background_progress), '' when nothing
export function backgroundText(n) {
  return n.background !== undefined && n.background !== null && n.background < 1
    ? `${n.background_message || 'background work'} ${Math.floor(n.background * 100)} %` : '';
}

// ``text`` broken into lines no wider than ``width`` (after '_', '-', ' ', '×' where it can,
// else anywhere); null where one character is already too wide
function wrapText(ctx, text, width) {
  if (ctx.measureText('M').width > width) return null;
  const lines = [];
  let line = '';
  for (const part of text.match(/[^_\- ×]+[_\- ×]*|[_\- ×]+/g) || []) {
    for (const piece of ctx.measureText(part).width <= width ? [part] : [...part]) {
      if (line && ctx.measureText(line + piece).width > width) { lines.push(line.trim()); line = ''; }
      line += piece;
    }
  }
  if (line.trim()) lines.push(line.trim());
  return lines;
}

export class Editor {
  // host: the element the canvas fills; catalogue: /api/nodes rows; hooks: {select, edit, refused, open}
  constructor(host, hooks) {
    this.host = host; this.hooks = hooks; this.catalogue = {};
    this.key = ''; this.pos = {}; this.nodes = {}; this.state = {}; this.thumbs = {};
    this.building = false; this.selected = null;
    const cv = document.createElement('canvas');
    cv.id = 'graph-canvas'; cv.tabIndex = 0;
    host.append(cv);
    this.graph = new LGraph();
    const editor = this;
    LGraphCanvas.prototype.processKey = function (e) { editor.onKey(e); };
    this.canvas = new LGraphCanvas(cv, this.graph);
    Object.assign(this.canvas, { allow_searchbox: false, render_canvas_border: false, show_info: false,
      allow_dragcanvas: true });
    this.canvas.onDrawForeground = ctx => this.drawFarLabels(ctx);
    this.canvas.onNodeSelected = n => { this.selected = n.gk; hooks.select(this.state[n.gk]?.members?.[0].name ?? n.gk); };
    this.canvas.onNodeDblClicked = n => this.rename(n.gk);
    this.minimap = document.createElement('canvas');
    this.minimap.id = 'minimap'; this.minimap.width = 180; this.minimap.height = 120;
    this.minimap.title = 'overview: click to look there';
    this.minimap.addEventListener('click', e => this.minimapClick(e));
    host.append(this.minimap);
    new ResizeObserver(() => this.resize()).observe(host);
    this.resize();
    const tick = () => { this.drawMinimap(); requestAnimationFrame(tick); };
    requestAnimationFrame(tick);
  }

  setCatalogue(rows) { this.catalogue = Object.fromEntries(rows.map(r => [r.type, r])); this.key = ''; }

  resize() {
    const r = this.host.getBoundingClientRect();
    this.canvas.resize(Math.max(50, r.width | 0), Math.max(50, r.height | 0));
  }

  // ---- drawing the server's state -------------------------------------------------------
  draw(all) {
    this.all = all;
    const nodes = collapse(all);
    const key = JSON.stringify(nodes.map(n => [n.name, n.type, n.missing, n.inputs, n.outputs]));
    if (key !== this.key) this.build(nodes, key);
    for (const n of nodes) this.show(n);
  }

  build(nodes, key) {
    this.key = key;
    this.building = true;
    for (const [name, n] of Object.entries(this.nodes)) this.pos[name] = [...n.pos];  // kept where the user left them
    this.graph.clear();
    this.nodes = {};
    for (const n of nodes) {
      const node = this.makeNode(n);
      this.graph.add(node);
      this.nodes[n.name] = node;
    }
    for (const n of nodes) {
      const dst = this.nodes[n.name];
      const seen = {};
      for (const [port, src, sport] of n.inputs) {
        const k = seen[port] = (seen[port] ?? -1) + 1;
        const i = dst.inputs.findIndex(s => s.gk.port === port && s.gk.index === (s.gk.variadic ? k : 0));
        const from = this.nodes[src];
        const o = from ? from.outputs.findIndex(s => s.name === sport) : -1;
        if (i >= 0 && o >= 0) from.connect(o, dst, i);
      }
    }
    this.building = false;
    const unplaced = nodes.filter(n => !this.pos[n.name]);
    for (const n of nodes) if (this.pos[n.name]) this.nodes[n.name].pos = [...this.pos[n.name]];
    if (unplaced.length) this.layout(unplaced.length === nodes.length);
    if (this.selected && this.nodes[this.selected]) this.canvas.selectNode(this.nodes[this.selected]);
    this.host.dataset.nodes = nodes.length;
    this.canvas.setDirty(true, true);
  }

  makeNode(n) {
    const spec = this.catalogue[n.type];
    const node = new LGraphNode(n.count ? `${n.name} ×${n.count}` : n.name);
    node.gk = n.name;
    node.gkType = n.type;
    const add = (label, type, gk) => { node.addInput(label, type); node.inputs.at(-1).gk = gk; };
    if (spec && !n.missing) {
      for (const [port, p] of Object.entries(spec.inputs)) {
        if (!p.variadic) { add(port + (p.optional ? '?' : ''), p.type, { port, index: 0 }); continue; }
        const count = n.inputs.filter(i => i[0] === port).length;
        for (let k = 0; k <= count; k++) add(`${port}[${k}]`, p.type, { port, index: k, variadic: true, type: p.type });
      }
    } else {  // a missing node type (plugin not installed): the inputs as written
      for (const port of [...new Set(n.inputs.map(i => i[0]))]) add(port, '*', { port, index: 0 });
    }
    for (const [port, t] of Object.entries(n.outputs || {})) node.addOutput(port, t);
    node.onConnectInput = (i, type, output, from) => this.building || (this.connect(from, output, node, i), false);
    node.onConnectionsChange = (kind, slot, connected) => {
      if (!this.building && kind === LiteGraph.INPUT && !connected) this.disconnect(node, slot);
    };
    node.onDrawForeground = ctx => this.drawInfo(node, ctx);
    node.onMouseDown = () => { if (node.thumbRect && this.overThumb(node)) this.hooks.open?.(node.thumbNode, node.thumbPort); };
    const base = node.computeSize();
    node.baseH = base[1];
    // room for a thumbnail from the start: the layout does not change as results come in
    node.hasImage = Object.values(n.outputs || {}).some(t => t === 'Image' || t === 'Mask');
    node.size = [W, base[1] + INFO + (node.hasImage ? THUMB : 0)];
    if (n.missing) { node.color = '#602020'; node.bgcolor = '#3a2020'; node.title = `${n.name} · missing ${n.type}`; }
    for (const s of [...node.inputs, ...node.outputs]) this.canvas.default_connection_color_byType[s.type] = typeColour(s.type);
    return node;
  }

  // one node's new state (a run's event); a sweep instance redraws its sweep's node
  update(n) {
    if (SWEPT.test(n.name) && this.all) {
      const g = collapse(this.all).find(x => x.name === base(n.name));
      return g && this.show(g);
    }
    this.show(n);
  }

  show(n) {
    const node = this.nodes[n.name];
    if (!node) return;
    const st = n.missing ? 'missing' : (n.state || 'idle');
    this.state[n.name] = n;
    node.gkState = st;
    if (!n.missing) node.boxcolor = STATE_COLOURS[st] || STATE_COLOURS.idle;
    const img = Object.entries(n.outputs || {}).find(([p, t]) => (t === 'Image' || t === 'Mask') && n.digests?.[p]);
    node.thumbPort = img ? img[0] : null;
    node.thumbNode = n.members ? n.members[0].name : n.name;  // a sweep: its first instance's
    if (img) this.thumb(n.name, node.thumbNode, img[0]);
    const h = node.baseH + INFO + (node.hasImage ? THUMB : 0) + (st === 'failed' || st === 'blocked' ? 26 : 0);
    if (node.size[1] !== h) node.size = [W, h];
    this.canvas.setDirty(true, false);
  }

  thumb(name, source, port) {
    const url = this.hooks.thumbURL(source, port, 96);
    const t = this.thumbs[name];
    if (t && t.url === url) return;
    const img = new Image();
    img.onload = () => this.canvas.setDirty(true, false);
    img.src = url;
    this.thumbs[name] = { url, img };
  }

  drawInfo(node, ctx) {
    const n = this.state[node.gk] || {};
    const st = node.gkState || 'idle';
    let y = node.baseH + 12;
    ctx.font = '11px system-ui, sans-serif';
    ctx.fillStyle = '#8a909c';
    ctx.textAlign = 'left';
    ctx.fillText(node.gkType, 8, y);
    const secs = st === 'running' ? (n.progress !== undefined ? `running ${Math.round(n.progress * 100)}%` : 'running')
      : (n.seconds !== null && n.seconds !== undefined ? `${st} ${n.seconds.toFixed(2)}s` : st)
      + (n.count ? ` ${n.done}/${n.count}` : '');
    ctx.fillStyle = STATE_COLOURS[st] || '#e05050';
    ctx.textAlign = 'right';
    ctx.fillText(secs, W - 8, y);
    ctx.textAlign = 'left';
    const bg = backgroundText(n);
    if (bg) {  // between the state line and the thumbnail
      ctx.font = '10px system-ui, sans-serif';
      ctx.fillStyle = STATE_COLOURS.running;
      let t = bg;
      while (t.length > 4 && ctx.measureText(t).width > W - 16) t = '…' + t.slice(2);
      ctx.fillText(t, 8, y + 12);
    }
    y += 16;
    if (st === 'failed' || st === 'blocked') {
      ctx.fillStyle = '#ff8080';
      const msg = (n.message || '').replace(/\s+/g, ' ');
      ctx.fillText(msg.slice(0, 34), 8, y);
      if (msg.length > 34) ctx.fillText(msg.slice(34, 68), 8, y + 13);
      y += 26;
    }
    const t = this.thumbs[node.gk];
    node.thumbRect = null;
    if (node.thumbPort && t?.img.complete && t.img.naturalWidth) {
      const s = Math.min((W - 16) / t.img.naturalWidth, (THUMB - 6) / t.img.naturalHeight);
      const w = t.img.naturalWidth * s, h = t.img.naturalHeight * s;
      node.thumbRect = [(W - w) / 2, y, w, h];
      ctx.drawImage(t.img, ...node.thumbRect);
    }
  }

  // zoomed out: names at LABEL_PX screen pixels, wrapped into each node's box; a name that
  // does not fit is left out (the node still shows its state colour)
  drawFarLabels(ctx) {
    const scale = this.canvas.ds.scale;
    if (scale >= FAR) return;
    const px = LABEL_PX / scale, TH = LiteGraph.NODE_TITLE_HEIGHT;
    ctx.save();
    ctx.font = `600 ${px}px system-ui, sans-serif`;
    ctx.textAlign = 'center';
    ctx.textBaseline = 'middle';
    let drawn = 0;
    for (const n of Object.values(this.nodes)) {
      const [x, y] = n.pos, w = n.size[0], h = n.size[1] + TH;
      const lines = wrapText(ctx, n.title, w - px / 2);
      if (!lines || lines.length * px * 1.2 > h) continue;
      const top = y - TH + (h - lines.length * px * 1.2) / 2 + px * 0.6;
      ctx.fillStyle = 'rgba(18,20,24,.8)';
      ctx.fillRect(x, top - px * 0.6, w, lines.length * px * 1.2);
      ctx.fillStyle = '#e8eaee';
      lines.forEach((l, i) => ctx.fillText(l, x + w / 2, top + i * px * 1.2));
      drawn += 1;
    }
    ctx.restore();
    this.host.dataset.labelled = drawn;
  }

  overThumb(node) {
    const [mx, my] = this.canvas.graph_mouse;
    const [x, y, w, h] = node.thumbRect;
    return mx >= node.pos[0] + x && mx <= node.pos[0] + x + w && my >= node.pos[1] + y && my <= node.pos[1] + y + h;
  }

  // ---- layout, view -----------------------------------------------------------------------
  async layout(fit = true) {
    const nodes = Object.values(this.nodes);
    const TH = LiteGraph.NODE_TITLE_HEIGHT;
    const g = {
      id: 'root',
      layoutOptions: { 'elk.algorithm': 'layered', 'elk.direction': 'RIGHT', 'elk.edgeRouting': 'SPLINES',
        'elk.layered.spacing.nodeNodeBetweenLayers': '60', 'elk.spacing.nodeNode': '24',
        'elk.layered.crossingMinimization.strategy': 'LAYER_SWEEP' },
      children: nodes.map(n => ({
        id: n.gk, width: n.size[0], height: n.size[1] + TH,
        layoutOptions: { 'elk.portConstraints': 'FIXED_ORDER' },
        ports: [...n.inputs.map((s, i) => ({ id: `${n.gk}/i${i}`, layoutOptions: { 'elk.port.side': 'WEST', 'elk.port.index': String(n.inputs.length - i) } })),
          ...n.outputs.map((s, i) => ({ id: `${n.gk}/o${i}`, layoutOptions: { 'elk.port.side': 'EAST', 'elk.port.index': String(i) } }))],
      })),
      edges: Object.values(this.graph.links || {}).filter(Boolean).map(l => ({
        id: `e${l.id}`, sources: [`${this.graph.getNodeById(l.origin_id).gk}/o${l.origin_slot}`],
        targets: [`${this.graph.getNodeById(l.target_id).gk}/i${l.target_slot}`] })),
    };
    const t0 = performance.now();
    const res = await layOut(g);
    this.layoutMs = performance.now() - t0;
    for (const c of res.children) {
      this.pos[c.id] = [c.x, c.y + TH];
      if (this.nodes[c.id]) this.nodes[c.id].pos = [c.x, c.y + TH];
    }
    if (fit) this.fit();
    this.host.dataset.laidOut = Object.keys(this.nodes).length;
    this.canvas.setDirty(true, true);
  }

  bounds() {
    const TH = LiteGraph.NODE_TITLE_HEIGHT;
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (const n of Object.values(this.nodes)) {
      x0 = Math.min(x0, n.pos[0]); y0 = Math.min(y0, n.pos[1] - TH);
      x1 = Math.max(x1, n.pos[0] + n.size[0]); y1 = Math.max(y1, n.pos[1] + n.size[1]);
    }
    return x0 === Infinity ? [0, 0, 1, 1] : [x0, y0, x1 - x0, y1 - y0];
  }

  fit() {
    const [x, y, w, h] = this.bounds();
    const cw = this.canvas.canvas.width / devicePixelRatio, ch = this.canvas.canvas.height / devicePixelRatio;
    const ds = this.canvas.ds;
    ds.scale = Math.max(0.1, Math.min(1.2, 0.94 * Math.min(cw / w, ch / h)));
    ds.offset[0] = (cw / ds.scale - w) / 2 - x;
    ds.offset[1] = (ch / ds.scale - h) / 2 - y;
    this.canvas.setDirty(true, true);
  }

  // where a graph point is drawn on the page (tests click nodes and sockets there)
  toPage([gx, gy]) {
    const r = this.canvas.canvas.getBoundingClientRect(), ds = this.canvas.ds;
    return [r.left + (gx + ds.offset[0]) * ds.scale, r.top + (gy + ds.offset[1]) * ds.scale];
  }
  nodePoint(name) { const n = this.nodes[name]; return this.toPage([n.pos[0] + 60, n.pos[1] - LiteGraph.NODE_TITLE_HEIGHT / 2]); }
  slotPoint(name, slot, input) {
    const n = this.nodes[name];
    const i = input ? n.inputs.findIndex(s => s.name === slot || (s.gk?.port === slot && !s.link)) : n.outputs.findIndex(s => s.name === slot);
    return this.toPage(n.getConnectionPos(input, i));
  }
  centre() {
    const ds = this.canvas.ds, c = this.canvas.canvas;
    return [c.width / devicePixelRatio / 2 / ds.scale - ds.offset[0] - W / 2, c.height / devicePixelRatio / 2 / ds.scale - ds.offset[1] - 40];
  }

  drawMinimap() {
    const m = this.minimap, ds = this.canvas.ds;
    const nodes = Object.values(this.nodes);
    m.hidden = nodes.length < 2;
    if (m.hidden) return;
    const [x, y, w, h] = this.bounds();
    const k = JSON.stringify([x, y, w, h, ds.offset, ds.scale, nodes.length, this.canvas.canvas.width, nodes.map(n => n.gkState).join()]);
    if (k === this.miniKey) return;
    this.miniKey = k;
    const s = Math.min((m.width - 8) / w, (m.height - 8) / h);
    this.mini = { x, y, s };
    const ctx = m.getContext('2d');
    ctx.clearRect(0, 0, m.width, m.height);
    ctx.fillStyle = 'rgba(20,22,26,.85)'; ctx.fillRect(0, 0, m.width, m.height);
    for (const n of nodes) {
      ctx.fillStyle = STATE_COLOURS[n.gkState] || '#a04040';
      ctx.fillRect(4 + (n.pos[0] - x) * s, 4 + (n.pos[1] - y) * s, Math.max(2, n.size[0] * s), Math.max(2, n.size[1] * s));
    }
    const c = this.canvas.canvas;
    ctx.strokeStyle = '#fff';
    ctx.strokeRect(4 + (-ds.offset[0] - x) * s, 4 + (-ds.offset[1] - y) * s,
      c.width / devicePixelRatio / ds.scale * s, c.height / devicePixelRatio / ds.scale * s);
  }

  minimapClick(e) {
    if (!this.mini) return;
    const { x, y, s } = this.mini, ds = this.canvas.ds, c = this.canvas.canvas;
    const gx = x + (e.offsetX - 4) / s, gy = y + (e.offsetY - 4) / s;
    ds.offset[0] = c.width / devicePixelRatio / 2 / ds.scale - gx;
    ds.offset[1] = c.height / devicePixelRatio / 2 / ds.scale - gy;
    this.canvas.setDirty(true, true);
  }

  // ---- edits (all through the server) ---------------------------------------------------
  connect(from, output, node, i) {
    const slot = node.inputs[i].gk;
    const ref = `${from.gk}.${output.name}`;
    let source = ref;
    if (slot.variadic) {
      source = (this.state[node.gk]?.inputs || []).filter(x => x[0] === slot.port).map(x => `${x[1]}.${x[2]}`);
      source.splice(slot.index, 1, ref);
    }
    this.hooks.edit([{ op: 'set_input', node: node.gk, port: slot.port, source }]);
  }

  disconnect(node, i) {
    const slot = node.inputs[i]?.gk;
    if (!slot) return;
    let source = null;
    if (slot.variadic) {
      source = (this.state[node.gk]?.inputs || []).filter(x => x[0] === slot.port).map(x => `${x[1]}.${x[2]}`);
      source.splice(slot.index, 1);
      if (!source.length) source = null;
    }
    this.hooks.edit([{ op: 'set_input', node: node.gk, port: slot.port, source }]);
  }

  freeName(type) {
    const stem = type.replace(/^[A-Z]+/, m => m.toLowerCase()).replace(/[^A-Za-z0-9_-]/g, '');
    let k = 1;
    while (this.nodes[`${stem}${k}`]) k += 1;
    return `${stem}${k}`;
  }

  // the first place from ``at`` downwards (then rightwards) where a new node overlaps none
  freeSpot([x, y]) {
    const H = 150, hit = (a, b) => Object.values(this.nodes).some(n =>
      a < n.pos[0] + n.size[0] + 10 && a + W + 10 > n.pos[0] && b < n.pos[1] + n.size[1] + 10 && b + H > n.pos[1] - 30);
    for (let k = 0; hit(x, y) && k < 400; k++) { y += 40; if (k % 12 === 11) { y -= 480; x += W + 30; } }
    return [x, y];
  }

  add(type, params, at) {
    const name = this.freeName(type);
    this.pos[name] = this.freeSpot(at || this.centre());
    return this.hooks.edit([{ op: 'add_node', name, type, ...(params ? { params } : {}) }]);
  }

  remove(name = this.selected) {
    if (name) this.hooks.edit([{ op: 'remove_node', name }]);
  }

  duplicate(name = this.selected) {
    const n = this.state[name];
    if (!n || n.missing) return;
    const p = this.nodes[name].pos;
    this.add(n.type, Object.keys(n.raw_params || {}).length ? n.raw_params : null, [p[0] + 30, p[1] + 30]);
  }

  rename(name = this.selected) {
    if (!name) return;
    const to = prompt(`rename node '${name}' to:`, name);
    if (!to || to === name) return;
    this.pos[to] = this.pos[name] || this.nodes[name]?.pos;
    if (this.selected === name) this.selected = to;
    this.hooks.edit([{ op: 'rename_node', name, new: to }]);
  }

  onKey(e) {
    if (e.type !== 'keydown' || e.target.localName === 'input') return;
    const ctrl = e.ctrlKey || e.metaKey;
    const act = (e.key === 'Delete' || e.key === 'Backspace') ? () => this.remove()
      : ctrl && e.key.toLowerCase() === 'z' ? () => this.hooks.undo(e.shiftKey)
      : ctrl && e.key.toLowerCase() === 'y' ? () => this.hooks.undo(true)
      : ctrl && e.key.toLowerCase() === 'd' ? () => this.duplicate()
      : e.key === 'F2' ? () => this.rename()
      : e.key === 'f' && !ctrl ? () => this.fit() : null;
    if (act) { e.preventDefault(); act(); }
  }

  select(name) {
    name = base(name);
    this.selected = name;
    const n = this.nodes[name];
    if (n && !this.canvas.selected_nodes?.[n.id]) this.canvas.selectNode(n);
  }
}
