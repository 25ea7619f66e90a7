// The palette: every node type the registry has (/api/nodes, as `graphkit nodes --json`
// gives it), searchable by type, doc and port types; a click adds the node to the graph.

function summary(doc) { return (doc || '').split('\n')[0]; }

function ports(r) {
  const c = p => Object.keys(p.constraints || {}).length ? ` ${JSON.stringify(p.constraints)}` : '';
  const ins = Object.entries(r.inputs).map(([k, p]) => `${k}${p.variadic ? '[]' : ''}${p.optional ? '?' : ''}: ${p.type}${c(p)}`);
  const outs = Object.entries(r.outputs).map(([k, p]) => `${k}: ${p.type}`);
  return `in ${ins.join(', ') || '—'} · out ${outs.join(', ') || '—'}`;
}

export function mountPalette(input, list, rows, onPick) {
  const items = rows.map(r => {
    const li = document.createElement('li');
    li.dataset.type = r.type;
    const b = document.createElement('b');
    b.textContent = r.type;
    const d = document.createElement('span');
    d.textContent = ' ' + summary(r.doc);
    const p = document.createElement('div');
    p.className = 'ports';
    p.textContent = ports(r);
    li.append(b, d, p);
    li.title = r.doc;
    li.addEventListener('click', () => onPick(r.type));
    return [li, `${r.type} ${r.doc} ${p.textContent}`.toLowerCase()];
  });
  list.replaceChildren(...items.map(([li]) => li));
  // shown: the types whose type, doc or ports hold every word; a type named by the search first
  const rank = li => { const t = li.dataset.type.toLowerCase(), q = input.value.trim().toLowerCase();
    return t === q ? 0 : t.startsWith(q) ? 1 : 2; };
  const filter = () => {
    const words = input.value.toLowerCase().split(/\s+/).filter(Boolean);
    for (const [li, text] of items) li.hidden = !words.every(w => text.includes(w));
    list.replaceChildren(...items.map(([li]) => li).sort((a, b) => rank(a) - rank(b)));
  };
  input.addEventListener('input', filter);
  input.addEventListener('keydown', e => {
    if (e.key !== 'Enter') return;
    const first = [...list.children].find(li => !li.hidden);
    if (first) onPick(first.dataset.type);
  });
}
