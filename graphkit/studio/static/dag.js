// The graph as an SVG DAG: one box per node (state colour, type, seconds, error), layered
// left to right by the server's layout (layer = longest path from a source).

const NS = 'http://www.w3.org/2000/svg';
const W = 168, H = 50, GX = 52, GY = 14;

function s(tag, attrs = {}, text) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

export class Dag {
  constructor(svg, onSelect) {
    this.svg = svg; this.onSelect = onSelect; this.boxes = {}; this.selected = null; this.key = '';
  }

  draw(nodes) {
    const key = JSON.stringify(nodes.map(n => [n.name, n.type, n.layer, n.row, n.inputs]));
    if (key !== this.key) this.build(nodes, key);
    for (const n of nodes) this.update(n);
  }

  build(nodes, key) {
    this.key = key;
    const svg = this.svg;
    svg.replaceChildren();
    const pos = {};
    let mx = 0, my = 0;
    for (const n of nodes) {
      const x = 10 + n.layer * (W + GX), y = 10 + n.row * (H + GY);
      pos[n.name] = [x, y];
      mx = Math.max(mx, x + W + 10); my = Math.max(my, y + H + 10);
    }
    svg.setAttribute('width', mx); svg.setAttribute('height', my);
    const edges = s('g');
    for (const n of nodes) {
      const [x2, y2] = pos[n.name];
      for (const [port, src] of n.inputs) {
        if (!pos[src]) continue;
        const [x1, y1] = pos[src];
        const a = [x1 + W, y1 + H / 2], b = [x2, y2 + H / 2];
        const dx = Math.max(20, (b[0] - a[0]) / 2);
        const p = s('path', { class: 'edge', d: `M${a[0]},${a[1]} C${a[0] + dx},${a[1]} ${b[0] - dx},${b[1]} ${b[0]},${b[1]}` });
        p.append(s('title', {}, `${src} → ${n.name}.${port}`));
        edges.append(p);
      }
    }
    svg.append(edges);
    this.boxes = {};
    for (const n of nodes) {
      const [x, y] = pos[n.name];
      const g = s('g', { class: 'node', transform: `translate(${x},${y})` });
      g.dataset.node = n.name;
      g.append(s('rect', { width: W, height: H }));
      g.append(s('text', { x: 8, y: 16, class: 'name' }, n.name));
      g.append(s('text', { x: 8, y: 30, class: 'type' }, n.type));
      g.append(s('text', { x: W - 8, y: 30, class: 'secs', 'text-anchor': 'end' }, ''));
      g.append(s('text', { x: 8, y: 44, class: 'msg' }, ''));
      const tip = s('title', {}, '');
      g.append(tip);
      g.addEventListener('click', () => this.onSelect(n.name));
      svg.append(g);
      this.boxes[n.name] = g;
    }
    if (this.selected) this.select(this.selected);
  }

  update(n) {
    const g = this.boxes[n.name];
    if (!g) return;
    const state = n.state || 'idle';
    g.setAttribute('class', `node ${state}${this.selected === n.name ? ' selected' : ''}`);
    g.dataset.state = state;
    const secs = g.querySelector('.secs');
    const frac = n.progress !== undefined && state === 'running' ? ` ${Math.round(n.progress * 100)}%` : '';
    secs.textContent = (state === 'running' ? 'running' + frac :
      (n.seconds !== null && n.seconds !== undefined ? `${state} ${n.seconds.toFixed(2)}s` : state));
    const msg = g.querySelector('.msg');
    msg.textContent = (state === 'failed' || state === 'blocked') ? (n.message || '').slice(0, 30) : '';
    g.querySelector('title').textContent = `${n.name} (${n.type}): ${state}${n.message ? '\n' + n.message : ''}`;
  }

  select(name) {
    if (this.selected && this.boxes[this.selected]) this.boxes[this.selected].classList.remove('selected');
    this.selected = name;
    if (this.boxes[name]) this.boxes[name].classList.add('selected');
  }
}
