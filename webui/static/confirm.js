// A question the page must ask before losing something: a modal <dialog> with a safe default.

import { h } from "./dom.js";
import { icon } from "./figures.js";

/**
 * Ask a yes/no question; resolves true when the person chose `leave`, false for `stay` or Escape.
 * The safe answer (`stay`) has the focus, so Enter or a stray tap does not lose anything.
 */
export function ask({ title, text, stay, leave }) {
  return new Promise((resolve) => {
    const stayBtn = h("button", { class: "button primary", type: "button", autofocus: true }, stay);
    const leaveBtn = h("button", { class: "button", type: "button" }, icon("cross"), leave);
    const dialog = h("dialog", { class: "ask", "aria-labelledby": "ask-title" },
      h("h2", { id: "ask-title" }, title),
      h("p", null, text),
      h("div", { class: "actions" }, leaveBtn, stayBtn));
    const done = (answer) => {
      dialog.close();
      dialog.remove();
      resolve(answer);
    };
    stayBtn.addEventListener("click", () => done(false));
    leaveBtn.addEventListener("click", () => done(true));
    dialog.addEventListener("cancel", (ev) => {
      ev.preventDefault();
      done(false);
    });
    document.body.append(dialog);
    dialog.showModal();
    stayBtn.focus();
  });
}
