// Step 0: the operator signs in with their name and their PIN (on a tablet the service trusts) or their secret.
// "My PIN" (#/pin) sets the PIN once signed in.

import { fill, h } from "./dom.js";
import { icon } from "./figures.js";

const MODE_KEY = "gyrocal.signin";

export function signInView(ctx, message, onDone) {
  let mode = localStorage.getItem(MODE_KEY) === "pin" ? "pin" : "secret";
  const name = h("input", { id: "operator", name: "operator", autocomplete: "username", required: true, autocapitalize: "none", spellcheck: "false" });
  const secret = h("input", { id: "secret", name: "secret", type: "password", autocomplete: "current-password" });
  const pin = h("input", { id: "pin", name: "pin", type: "password", inputmode: "numeric", pattern: "[0-9]*", maxlength: "8", autocomplete: "off", class: "pin-input" });
  const secretField = h("div", { class: "field" }, h("label", { for: "secret" }, "Your secret"), secret);
  const pinField = h("div", { class: "field" }, h("label", { for: "pin" }, "Your PIN (4 to 8 digits)"), pin);
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const submit = h("button", { class: "button primary big", type: "submit" }, "Sign in");
  const tabs = ["pin", "secret"].map((m) => h("button", { class: `button mode mode-${m}`, type: "button", "aria-pressed": "false",
    onclick: () => setMode(m, true) }, m === "pin" ? "With my PIN" : "With my secret"));
  const form = h("form", { class: "signin", novalidate: true },
    h("div", { class: "mode-switch", role: "group", "aria-label": "Sign in with" }, tabs),
    h("label", { for: "operator" }, "Your operator name"), name,
    pinField, secretField, error, submit);

  const showError = (text) => {
    error.hidden = false;
    error.replaceChildren(icon("warn"), h("span", null, text));
  };
  const setMode = (m, focus) => {
    mode = m;
    localStorage.setItem(MODE_KEY, m);
    form.dataset.mode = m;
    pinField.hidden = m !== "pin";
    secretField.hidden = m !== "secret";
    tabs.forEach((t, i) => t.setAttribute("aria-pressed", String(["pin", "secret"][i] === m)));
    if (focus) (name.value.trim() ? (m === "pin" ? pin : secret) : name).focus();
  };
  setMode(mode, false);
  if (message) showError(`${message}`);

  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const field = mode === "pin" ? pin : secret;
    if (!name.value.trim() || !field.value) {
      showError(`Enter your operator name and your ${mode === "pin" ? "PIN" : "secret"}.`);
      (name.value.trim() ? field : name).focus();
      return;
    }
    if (mode === "pin" && !/^[0-9]{4,8}$/.test(pin.value)) {
      showError("A PIN is 4 to 8 digits.");
      pin.select();
      return;
    }
    submit.disabled = true;
    submit.textContent = "Signing in…";
    try {
      await ctx.api.signIn(name.value.trim(), secret.value, mode === "pin" ? { pin: pin.value } : {});
      onDone();
    } catch (err) {
      submit.disabled = false;
      submit.textContent = "Sign in";
      if (err.network) showError("The gyrocal service cannot be reached. Check that it is running, then try again.");
      else if (err.status === 401 && mode === "secret") showError("That name and secret do not match an operator. Check them and try again; an administrator can reset your secret.");
      else if (err.status === 401 && /switched off/.test(err.detail || "")) showError(err.detail);
      else if (err.status === 401) showError("That name and PIN do not match. Check them and try again, or sign in with your secret.");
      else showError(err.detail);
      field.select();
    }
  });

  fill(ctx.main, h("section", { class: "panel narrow", "aria-labelledby": "signin-title" },
    h("h1", { id: "signin-title" }, "Sign in to calibrate"),
    h("p", { class: "lead" }, "Calibrations are saved under your name."),
    form));
  name.focus();
}

/** #/pin: the signed-in operator sets (or removes) the PIN they sign in with on this tablet. */
export function pinView(ctx) {
  const pin = h("input", { id: "new-pin", type: "password", inputmode: "numeric", pattern: "[0-9]*", maxlength: "8", autocomplete: "off", class: "pin-input" });
  const again = h("input", { id: "new-pin-again", type: "password", inputmode: "numeric", pattern: "[0-9]*", maxlength: "8", autocomplete: "off", class: "pin-input" });
  const status = h("p", { class: "form-error", role: "alert", hidden: true });
  const say = (kind, text) => {
    status.hidden = false;
    status.className = kind === "ok" ? "form-ok" : "form-error";
    status.replaceChildren(icon(kind === "ok" ? "check" : "warn"), h("span", null, text));
  };
  const save = h("button", { class: "button primary big", type: "submit" }, icon("save"), "Save my PIN");
  const form = h("form", { class: "signin", novalidate: true },
    h("label", { for: "new-pin" }, "New PIN (4 to 8 digits)"), pin,
    h("label", { for: "new-pin-again" }, "The same PIN again"), again, status, save);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (!/^[0-9]{4,8}$/.test(pin.value)) return say("error", "A PIN is 4 to 8 digits.");
    if (pin.value !== again.value) return say("error", "The two PINs differ. Type the same PIN twice.");
    save.disabled = true;
    try {
      await ctx.api.request("PUT", "/auth/pin", { json: { pin: pin.value } });
      pin.value = again.value = "";
      say("ok", "Saved. Next time, choose “With my PIN” when you sign in on this tablet.");
    } catch (err) {
      if (err.status !== 401) say("error", err.network ? "The gyrocal service cannot be reached; try again." : err.detail);
    } finally {
      save.disabled = false;
    }
  });
  fill(ctx.main, h("section", { class: "panel narrow", "aria-labelledby": "pin-title" },
    h("h1", { id: "pin-title" }, "My PIN"),
    h("p", { class: "lead" }, `A short PIN lets ${ctx.api.operator} sign in on the ward's tablets without the long secret. Ten wrong PINs in a row switch it off.`),
    form,
    h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list")));
  ctx.title("My PIN");
  pin.focus();
}
