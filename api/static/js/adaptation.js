// The arm's online adaptation (arm.adapt, daemon/arm/adaptation.py): each adapted factor of the
// shown run's latest step with its 1-sigma, as the step records them (observer_json: name ->
// [value, 1-sigma]; heat:J, alpha and convection are factors of the model's, share the part of
// a joint's heat on the motor's side of the link). Shown on arm runs that adapt, hidden
// otherwise. Every value reaches the page through textContent.
import { $, element, naturally, parsed } from "./util.js";

let shownStep = -1;

export function clearAdaptation() {
  shownStep = -1;
  $("adaptation").hidden = true;
  $("adaptation-rows").replaceChildren();
  $("adaptation-step").textContent = "";
}

function digits(sigma) {
  // as many decimals as the 1-sigma's first significant digit needs (2 to 4)
  if (!(sigma > 0)) return 3;
  return Math.min(4, Math.max(2, 1 - Math.floor(Math.log10(sigma))));
}

// an arm step's estimates, when it is the latest seen
export function showAdaptation(step) {
  if (!step.observer_json || step.step < shownStep) return;
  const estimates = parsed(step.observer_json);
  const names = Object.keys(estimates).filter((name) => Array.isArray(estimates[name])
    && estimates[name].length === 2).sort(naturally);
  if (!names.length) return;
  shownStep = step.step;
  const rows = names.map((name) => {
    const [value, sigma] = estimates[name].map(Number);
    const n = digits(sigma);
    const row = element("tr");
    row.dataset.name = name;
    row.append(element("th", "", name), element("td", "value", value.toFixed(n)),
      element("td", "sigma", `± ${sigma.toFixed(n)}`));
    return row;
  });
  $("adaptation-rows").replaceChildren(...rows);
  $("adaptation-step").textContent = `step ${step.step}`;
  $("adaptation").hidden = false;
}
