// Studio live view of Relight: a slider per real light over the linear fast path.
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  const d = api.data;
  return sliderView(el, api, { sliders: d.sliders, note: d.note, live: d.fast });
}
