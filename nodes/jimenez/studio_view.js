// Studio live view of AppearanceRig: rig-weight and hemoglobin-scale sliders, whole-photo preview.
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  return sliderView(el, api, { sliders: api.data.sliders, note: api.data.note });
}
