// Step 0: the operator signs in with their name and secret.

import { fill, h } from "./dom.js";
import { icon } from "./figures.js";

export function signInView(ctx, message, onDone) {
  const name = h("input", { id: "operator", name: "operator", autocomplete: "username", required: true, autocapitalize: "none", spellcheck: "false" });
  const secret = h("input", { id: "secret", name: "secret", type: "password", autocomplete: "current-password", required: true });
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const submit = h("button", { class: "button primary big", type: "submit" }, "Sign in");
  const form = h("form", { class: "signin", novalidate: true },
    h("label", { for: "operator" }, "Your operator name"), name,
    h("label", { for: "secret" }, "Your secret"), secret,
    error, submit);

  const showError = (text) => {
    error.hidden = false;
    error.replaceChildren(icon("warn"), h("span", null, text));
  };
  if (message) showError(`${message}`);

  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (!name.value.trim() || !secret.value) {
      showError("Enter your operator name and your secret.");
      (name.value.trim() ? secret : name).focus();
      return;
    }
    submit.disabled = true;
    submit.textContent = "Signing in…";
    try {
      await ctx.api.signIn(name.value.trim(), secret.value);
      onDone();
    } catch (err) {
      submit.disabled = false;
      submit.textContent = "Sign in";
      if (err.network) showError("The gyrocal service cannot be reached. Check that it is running, then try again.");
      else if (err.status === 401) showError("That name and secret do not match an operator. Check them and try again; an administrator can reset your secret.");
      else showError(err.detail);
      secret.select();
    }
  });

  fill(ctx.main, h("section", { class: "panel narrow", "aria-labelledby": "signin-title" },
    h("h1", { id: "signin-title" }, "Sign in to calibrate"),
    h("p", { class: "lead" }, "Calibrations are saved under your name."),
    form));
  name.focus();
}
