// The clinician's wizard page: routing between sign-in, device list, the guided session and history.
// The URL hash names what is shown (#/session/<id> etc.), so a reload resumes from the service's state.

import { Api } from "./api.js";
import { fill, h } from "./dom.js";
import { icon } from "./figures.js";
import { requestProblem } from "./messages.js";
import { devicesView } from "./devices.js";
import { fleetView } from "./fleet.js";
import { historyView } from "./history.js";
import { kitView } from "./kit.js";
import { pinView, signInView } from "./signin.js";
import { noiseView } from "./noise.js";
import { uploadView } from "./upload.js";
import { placeView, sessionView } from "./wizard.js";

const api = new Api();
const main = document.getElementById("view");
const who = document.getElementById("who");
const banner = document.getElementById("banner");
let cleanup = null;
let afterSignIn = null;
let leaveGuard = null; // the view's question before it is left (an unsaved PASS): async () => true to leave
let shownHash = null; // the route on screen

const ROUTES = [
  [/^#\/devices$/, () => devicesView(ctx)],
  [/^#\/place\/([^/]+)$/, (m) => placeView(ctx, decodeURIComponent(m[1]))],
  [/^#\/session\/([0-9a-f]{32})$/, (m) => sessionView(ctx, m[1])],
  [/^#\/kit\/([0-9a-f]{32})$/, (m) => kitView(ctx, m[1])],
  [/^#\/history\/([^/]+)$/, (m) => historyView(ctx, decodeURIComponent(m[1]))],
  [/^#\/upload$/, () => uploadView(ctx)],
  [/^#\/noise$/, () => noiseView(ctx)],
  [/^#\/fleet$/, () => fleetView(ctx)],
  [/^#\/pin$/, () => pinView(ctx)],
];

const ctx = {
  api,
  main,
  /** Go to a hash route; replace=true keeps the browser's back button from returning to it. */
  go(hash, replace = false) {
    if (location.hash === hash) route();
    else if (replace) {
      history.replaceState(null, "", hash);
      route();
    } else location.hash = hash;
  },
  /** Ask ``question`` (async, true: leave) before this view is left: a link, Back, a reload or closing the tab.
   * Back is caught by an extra history entry of this view's own: going back to the entry beneath asks. */
  guardLeave(question) {
    leaveGuard = question;
    if (question && !(history.state && history.state.guard)) history.pushState({ guard: true }, "", location.hash);
  },
  title(text) {
    document.title = text ? `${text} · gyrocal` : "gyrocal";
  },
  /** What an event stream's link (api.stream's onLink) shows: a banner while it reconnects, none once it is open. */
  streamLink(link) {
    if (link === "retrying") ctx.banner("warn", "The connection to the service was interrupted. Reconnecting…");
    else if (link === "open") ctx.banner(null);
  },
  /** A banner above the page (the link to the service); null hides it. */
  banner(kind, text) {
    if (!text) {
      banner.hidden = true;
      banner.replaceChildren();
      return;
    }
    banner.hidden = false;
    banner.className = `banner ${kind}`;
    banner.replaceChildren(icon(kind === "warn" ? "warn" : "info"), h("span", null, text));
  },
  /** A failed request as a full-page message with what to do. */
  problem(err, what, actions = []) {
    const p = requestProblem(err, what);
    if (p.signIn) return signOutAndAsk(err.detail);
    ctx.title(p.title);
    fill(main, h("section", { class: "panel problem", "aria-labelledby": "problem-title" },
      h("div", { class: "verdict warn" }, icon("warn"), h("h1", { id: "problem-title" }, p.title)),
      h("p", { class: "lead" }, p.text),
      h("p", null, p.fix),
      h("div", { class: "actions" },
        ...actions,
        h("button", { class: "button", type: "button", onclick: () => route() }, icon("redo"), "Try again"),
        h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list"))));
    focusMain();
  },
};

function focusMain() {
  main.focus({ preventScroll: true });
  window.scrollTo(0, 0);
}
ctx.focusMain = focusMain;

function renderWho() {
  if (!api.signedIn) {
    who.replaceChildren();
    return;
  }
  who.replaceChildren(
    h("span", { class: "who-name" }, icon("user"), h("span", null, api.operator)),
    api.operator !== "api" ? h("a", { class: "button small", href: "#/pin" }, "My PIN") : null,
    h("button", { class: "button small", type: "button", onclick: async () => {
      await api.signOut();
      renderWho();
      ctx.go("#/devices");
    } }, "Sign out"));
}

function signOutAndAsk(message) {
  api.forget();
  renderWho();
  afterSignIn = location.hash && location.hash !== "#/signin" ? location.hash : "#/devices";
  showSignIn(message);
}

function showSignIn(message) {
  if (cleanup) cleanup();
  cleanup = null;
  ctx.title("Sign in");
  signInView(ctx, message, () => {
    renderWho();
    const next = afterSignIn || "#/devices";
    afterSignIn = null;
    ctx.go(next, true);
  });
}

/** Back from a guarded view (to the entry beneath its own): ask; staying puts the guard entry back. */
async function onPopState() {
  if (!leaveGuard || location.hash !== shownHash || (history.state && history.state.guard)) return;
  const question = leaveGuard;
  if (await question()) {
    if (leaveGuard === question) leaveGuard = null;
    history.back();
  } else history.pushState({ guard: true }, "", shownHash);
}

/** A new hash: ask the view's question first, showing the view, and its own address, until it is answered. */
async function onHashChange() {
  if (location.hash === shownHash) return; // back onto the view on screen (a question answered "stay")
  if (leaveGuard) {
    const question = leaveGuard;
    const target = location.hash;
    // the link or Forward that was followed is undone at once: the address names what is on screen while she reads
    // the question, and after "stay"; "leave" follows it again
    const back = new Promise((resolve) => window.addEventListener("popstate", resolve, { once: true }));
    history.back();
    await back;
    if (!(await question())) return;
    if (leaveGuard === question) leaveGuard = null;
    location.hash = target;
    return;
  }
  route();
}

function route() {
  if (cleanup) {
    cleanup();
    cleanup = null;
  }
  leaveGuard = null;
  shownHash = location.hash;
  ctx.banner(null);
  if (!api.signedIn) {
    afterSignIn = location.hash && location.hash !== "#/signin" ? location.hash : "#/devices";
    showSignIn();
    return;
  }
  const hash = location.hash || "#/devices";
  for (const [re, make] of ROUTES) {
    const m = hash.match(re);
    if (m) {
      cleanup = make(m) || null;
      return;
    }
  }
  history.replaceState(null, "", "#/devices");
  cleanup = devicesView(ctx) || null;
}

async function start() {
  api.onUnauthorized = (err) => signOutAndAsk(err.detail);
  window.addEventListener("hashchange", onHashChange);
  window.addEventListener("popstate", onPopState);
  window.addEventListener("beforeunload", (ev) => {
    if (!leaveGuard) return;
    ev.preventDefault();
    ev.returnValue = ""; // the browser asks; what it says is its own
  });
  try {
    await api.health();
  } catch (err) {
    ctx.problem(err, "load the page");
    return;
  }
  if (api.signedIn) {
    try {
      await api.get("/auth/me");
    } catch (err) {
      if (err.status === 401) return; // the operator is asked to sign in again
    }
  }
  renderWho();
  route();
}

start();
