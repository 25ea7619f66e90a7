// Studio live view of CompositeFace: the first light of its Render moved by two sliders, the whole photo relit.
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  return sliderView(el, api, { sliders: api.data.sliders, note: api.data.note });
}
