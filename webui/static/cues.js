// Sound for eyes that are on the device, not the screen: a short tone at each step (a lower one for a warning) and,
// where the browser can speak, the prompts read aloud. Both off until she turns them on; the choice is remembered.

import { h } from "./dom.js";
import { icon } from "./figures.js";

const KEYS = { sound: "gyrocal.sound", speech: "gyrocal.speech" };
const TONES = { step: [880, 0.12], done: [1320, 0.25], warn: [330, 0.3] }; // Hz, s
const TONE_GAP_S = 0.06; // silence between two tones, so that each is heard as one
const WARN_CLEAR_S = 0.5; // after a warning's tone, no step's tone for this long

// one audio clock for the page, whichever view plays a tone
let audio = null;
let free = 0; // the audio clock's time from which a new tone does not overlap the one before
let warnEnds = -1; // ... and until which a step's tone would follow a warning's too closely to be heard apart

const remembered = (key) => {
  try { return localStorage.getItem(key) === "on"; } catch { return false; }
};
const remember = (key, on) => {
  try { localStorage.setItem(key, on ? "on" : "off"); } catch { /* private mode: for this page only */ }
};

/** The page's cues: ``tone(kind)``, ``say(text)`` and ``controls()`` (the two switches). ``current``: the prompt on
 * the screen now, read at once when she turns Read aloud on (else she would hear nothing until the next one). */
export function cues({ current = null } = {}) {
  const on = { sound: remembered(KEYS.sound), speech: remembered(KEYS.speech) };
  const canSpeak = typeof window.speechSynthesis !== "undefined" && typeof window.SpeechSynthesisUtterance !== "undefined";
  const canSound = typeof window.AudioContext !== "undefined";

  /** A tone, never over another: each starts once the one before has ended. A step's tone that would come within a
   * moment of a warning's is not played (a knock's notice changes the screen too: two step tones 30-50 ms after the
   * 330 Hz warning masked it). */
  const tone = (kind) => {
    if (!on.sound || !canSound) return;
    audio = audio || new AudioContext();
    if (audio.state === "suspended") audio.resume();
    const [hz, s] = TONES[kind] || TONES.step;
    const at = Math.max(audio.currentTime, free);
    if (kind === "step" && at < warnEnds) return;
    const osc = audio.createOscillator();
    const gain = audio.createGain();
    osc.frequency.value = hz;
    gain.gain.setValueAtTime(0.2, at);
    gain.gain.exponentialRampToValueAtTime(0.001, at + s);
    osc.connect(gain).connect(audio.destination);
    osc.start(at);
    osc.stop(at + s);
    free = at + s + TONE_GAP_S;
    if (kind === "warn") warnEnds = free + WARN_CLEAR_S;
  };

  let said = "";
  // ``queued``: after what is being read, not instead of it
  const say = (text, queued = false) => {
    if (!on.speech || !canSpeak || !text || text === said) return;
    said = text;
    if (!queued) window.speechSynthesis.cancel(); // the newest prompt only: an old one read late would be wrong
    window.speechSynthesis.speak(new SpeechSynthesisUtterance(text));
  };

  const toggle = (what, label, glyph, available, why) => {
    const state = h("span", { class: "cue-state", "aria-hidden": "true" });
    const b = h("button", { class: `button cue-toggle cue-${what}`, type: "button", "aria-pressed": String(on[what] && available) },
      icon(glyph), label, state);
    const show = () => { state.textContent = on[what] && available ? "on" : "off"; };
    show();
    if (!available) {
      b.disabled = true;
      b.title = why;
    }
    b.addEventListener("click", () => {
      on[what] = !on[what];
      remember(KEYS[what], on[what]);
      b.setAttribute("aria-pressed", String(on[what]));
      show();
      if (what === "sound") tone("step"); // the click is the gesture a browser asks before it plays sound
      if (what === "speech") {
        said = "";
        say(on.speech ? "Prompts will be read aloud." : "");
        if (current) say(current(), true);
      }
    });
    return b;
  };

  const controls = () => h("div", { class: "cue-toggles", role: "group", "aria-label": "Sound" },
    toggle("sound", "Sound", "bell", canSound, "This browser cannot play sound."),
    toggle("speech", "Read aloud", "speaker", canSpeak, "This browser cannot read aloud."));

  return { tone, say, controls };
}
