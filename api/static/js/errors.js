// The errors panel: the daemon's latest device and run errors (the snapshot's list, then each
// streamed "error" event), newest first. A move refused because the robot was held
// (kind "motion-held", drivers/permit.py) is the hold doing its job after Hold, Stop, a fault
// or a shutdown, not a fault of its own: it is listed, greyed and explained, and counted apart
// so that "Errors (none)" still means nothing went wrong. Every value reaches the page through
// textContent.
import { $, element } from "./util.js";

const MAX_SHOWN = 50;
const HELD_KIND = "motion-held";
const counts = { errors: 0, held: 0 };

function showCount() {
  const parts = [];
  if (counts.errors) parts.push(`(${counts.errors})`);
  else parts.push("(none)");
  if (counts.held) {
    parts.push(`· ${counts.held} ${counts.held === 1 ? "move" : "moves"} refused by a hold`);
  }
  $("error-count").textContent = parts.join(" ");
}

function item(entry) {
  const held = entry.kind === HELD_KIND;
  const node = element("li", held ? "expected" : "");
  const meta = element("span", "meta");
  const when = entry.time ? new Date(entry.time * 1000).toLocaleTimeString() : "";
  meta.textContent = `${when} ${entry.device || ""} ${entry.kind || ""}: `;
  node.append(meta, document.createTextNode(entry.message || ""));
  if (held) {
    node.append(element("span", "why",
      " (expected: the robot was held, so this move was refused and nothing was sent)"));
  }
  return node;
}

// the snapshot's whole list (oldest first)
export function showErrors(errors) {
  counts.errors = errors.filter((entry) => entry.kind !== HELD_KIND).length;
  counts.held = errors.length - counts.errors;
  $("error-list").replaceChildren(...errors.slice(-MAX_SHOWN).reverse().map(item));
  showCount();
}

// one streamed error, newest: at the top
export function addError(entry) {
  if (entry.kind === HELD_KIND) counts.held += 1; else counts.errors += 1;
  const list = $("error-list");
  list.prepend(item(entry));
  while (list.children.length > MAX_SHOWN) list.lastChild.remove();
  showCount();
}
