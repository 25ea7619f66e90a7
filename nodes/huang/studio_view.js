// Studio live view of CosmeticShade / KMStack: a thickness slider per layer, whole-photo preview.
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  return sliderView(el, api, { sliders: api.data.sliders, note: api.data.note });
}
