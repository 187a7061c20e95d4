// Telling wearables apart: "Identify" asks one to blink its light (or buzz) for a few seconds.

import { h } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";

/** An "Identify" button and its status line for a wearable whose protocol can blink (``dev.identify``), else null. */
export function identifyButton(api, dev) {
  if (!dev.identify || !dev.available) return null;
  const name = dev.name || dev.id;
  const line = h("p", { class: "identify-status", role: "status" });
  const button = h("button", { class: "button identify", type: "button", "aria-label": `Identify ${name}: make it blink` },
    icon("blink"), "Identify");
  let timer = null;
  button.addEventListener("click", async () => {
    button.disabled = true;
    line.className = "identify-status";
    line.textContent = `Asking ${name} to blink…`;
    try {
      const out = await api.post(`/devices/${encodeURIComponent(dev.id)}/identify`, {});
      line.classList.add("ok");
      line.replaceChildren(icon("check"), h("span", null, `${out.message} Look for it on the table.`));
      clearTimeout(timer);
      timer = setTimeout(() => { line.replaceChildren(); line.className = "identify-status"; }, out.seconds * 1000);
    } catch (err) {
      line.classList.add("error");
      line.replaceChildren(icon("warn"), h("span", null, err.status === 401 ? "Please sign in again." : problemLine(err)));
    } finally {
      button.disabled = false;
    }
  });
  return { button, line };
}
