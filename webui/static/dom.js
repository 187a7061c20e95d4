// Tiny DOM helpers: build elements and SVG without a framework, and format values for people.

const SVG_NS = "http://www.w3.org/2000/svg";

function append(el, children) {
  for (const c of children.flat(Infinity)) {
    if (c === null || c === undefined || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

function setAttrs(el, attrs) {
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") el.addEventListener(k.slice(2), v);
    else if (k === "class") el.setAttribute("class", Array.isArray(v) ? v.filter(Boolean).join(" ") : v);
    else if (k === "dataset") Object.assign(el.dataset, v);
    else el.setAttribute(k, v === true ? "" : String(v));
  }
  return el;
}

/** An HTML element: h("button", {class: "big", onclick}, "Start"). */
export function h(tag, attrs, ...children) {
  return append(setAttrs(document.createElement(tag), attrs), children);
}

/** An SVG element: s("circle", {cx: 5, cy: 5, r: 4}). */
export function s(tag, attrs, ...children) {
  return append(setAttrs(document.createElementNS(SVG_NS, tag), attrs), children);
}

export function clear(el) {
  while (el.firstChild) el.firstChild.remove();
  return el;
}

/** Replace an element's children. */
export function fill(el, ...children) {
  return append(clear(el), children);
}

const dateFmt = new Intl.DateTimeFormat(undefined, { day: "numeric", month: "short", year: "numeric" });
const timeFmt = new Intl.DateTimeFormat(undefined, { hour: "2-digit", minute: "2-digit" });

export function parseTime(iso) {
  if (!iso) return null;
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? null : d;
}

/** "21 Nov 2026" */
export function fmtDate(iso) {
  const d = parseTime(iso);
  return d ? dateFmt.format(d) : "—";
}

/** "08:13" */
export function fmtTime(d) {
  return timeFmt.format(d);
}

/** "21 Nov 2026, 08:13" */
export function fmtDateTime(iso) {
  const d = parseTime(iso);
  return d ? `${dateFmt.format(d)}, ${timeFmt.format(d)}` : "—";
}

/** A number with a fixed number of decimals, or a dash. */
export function num(v, digits = 3) {
  return typeof v === "number" && Number.isFinite(v) ? v.toFixed(digits) : "—";
}

/** A standard error in a compact form: 2.5e-5 -> "0.000025". */
export function sig(v, digits = 2) {
  if (typeof v !== "number" || !Number.isFinite(v)) return "—";
  if (v === 0) return "0";
  return Number(v.toPrecision(digits)).toString();
}

export const AXES = ["x", "y", "z"];
export const AXIS_LABEL = { x: "X", y: "Y", z: "Z" };
