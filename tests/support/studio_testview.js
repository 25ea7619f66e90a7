// The test live view (tests/support/studionodes.py): the engine's slider kit.
import { sliderView } from '/static/viewkit.js';

export function mount(el, api) {
  return sliderView(el, api, { sliders: api.data.sliders });
}
