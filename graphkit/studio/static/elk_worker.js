// ELK's layered layout in a Web Worker, so laying out a big graph never blocks the page.
// Messages: {id, graph} in, {id, graph} or {id, error} out.
importScripts('/static/vendor/elkjs-0.12.1/elk.bundled.js');
const elk = new ELK();
// set after ELK is made: its in-worker stand-in registers its own self.onmessage when loaded
self.onmessage = async ({ data: { id, graph } }) => {
  try { self.postMessage({ id, graph: await elk.layout(graph) }); }
  catch (e) { self.postMessage({ id, error: String(e && e.message || e) }); }
};
