// The errors panel: the daemon's latest device and run errors (the snapshot's list, then each
// streamed "error" event), newest first. A move refused because a person or the daemon asked
// for the hold (kind "motion-held", drivers/permit.py, with the request's reason: Hold robot,
// Pause, Stop, a shutdown; daemon/service.py) is the hold doing its job, not a fault: it is
// listed, greyed and explained, and counted apart so that "Errors (none)" still means nothing
// went wrong. A hold with any other reason (a lost link, a fault) stays an error. Every value
// reaches the page through textContent.
import { $, element } from "./util.js";

const MAX_SHOWN = 50;
const HELD_KIND = "motion-held";
// the reasons of the holds that were asked for (daemon/service.py HOLD_REASON, pause, stop,
// api/serve.py's shutdown; drivers/permit.py's refusal of a motion older than a hold)
const ASKED = /(by request|daemon shutting down|a hold came after this motion was requested)$/;
const counts = { errors: 0, held: 0 };

function asked(entry) {
  return entry.kind === HELD_KIND && ASKED.test(String(entry.message || ""));
}

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
  const held = asked(entry);
  const node = element("li", held ? "expected" : "");
  const meta = element("span", "meta");
  const when = entry.time ? new Date(entry.time * 1000).toLocaleTimeString() : "";
  meta.textContent = `${when} ${entry.device || ""} ${entry.kind || ""}: `;
  node.append(meta, document.createTextNode(entry.message || ""));
  if (held) {
    node.append(element("span", "why",
      " (expected: the robot was held on request, so this move was refused and nothing was sent)"));
  }
  return node;
}

// the snapshot's whole list (oldest first)
export function showErrors(errors) {
  counts.errors = errors.filter((entry) => !asked(entry)).length;
  counts.held = errors.length - counts.errors;
  $("error-list").replaceChildren(...errors.slice(-MAX_SHOWN).reverse().map(item));
  showCount();
}

// one streamed error, newest: at the top
export function addError(entry) {
  if (asked(entry)) counts.held += 1; else counts.errors += 1;
  const list = $("error-list");
  list.prepend(item(entry));
  while (list.children.length > MAX_SHOWN) list.lastChild.remove();
  showCount();
}
