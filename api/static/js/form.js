// The run form adapts to the daemon's run kind: a two-link daemon asks for the procedure,
// network, deformation scale and heater switch-off; an arm daemon for the duty cycle and the
// arm model. Both: compensation, duration, step, time scale and the uncompensated reference
// run the drift removed is measured against. Empty fields take the configured value, shown
// as the placeholder.
import { api } from "./api.js";
import { $, element } from "./util.js";

const FINAL_STATES = ["finished", "stopped"];

function option(value, text, title) {
  const node = element("option", "", text);
  node.value = value;
  if (title) node.title = title;
  return node;
}

async function loadNetworks() {
  try {
    const list = await api("GET", "/networks");
    for (const network of list.networks) {
      const found = network.identification;
      // an identified network says where it came from (issue 19): its source runs and date
      $("network-select").append(option(network.name,
        found ? `${network.name} (identified from ${found.source_runs.join(", ")})`
          : network.name,
        found ? `${network.description}\nidentified ${found.identified_at} from `
          + `${found.base_network}` : network.description));
    }
  } catch { /* the list is a convenience; the config's network is the default */ }
}

// the identified arm models saved in the data directory, each saying where it came from
async function loadArmModels() {
  const list = await api("GET", "/arm-models");
  for (const model of list.arm_models || []) {
    const fit = model.marker_rms_um === null
      ? "" : `, fit RMS ${model.marker_rms_um.toFixed(2)} µm`;
    $("arm-model-select").append(option(model.name,
      `${model.name} (identified from ${model.source_runs.join(", ")})`,
      `arm ${model.arm}, duty cycle ${model.duty_cycle}, identified ${model.identified_at}${fit}`));
  }
  return Boolean(list.arm_runs);
}

// the duty cycles a run may name: the API description's own list (RunRequest.duty_cycle)
async function loadDutyCycles() {
  try {
    const response = await fetch("/openapi.json");
    const description = await response.json();
    const field = description.components.schemas.RunRequest.properties.duty_cycle;
    const names = (field.anyOf || [field]).flatMap((item) => item.enum || []);
    for (const name of names) if (name) $("duty-select").append(option(name, name));
  } catch { /* the configured duty cycle is the default */ }
}

async function loadDefaults() {
  try {
    const config = await api("GET", "/config");
    const scheduler = config.scheduler || {};
    const compensation = config.compensation || {};
    const placeholders = {
      duration_s: scheduler.duration_s,
      step_s: scheduler.step_s,
      time_scale: compensation.time_scale,
      deformation_scale: compensation.deformation_scale,
    };
    for (const [name, value] of Object.entries(placeholders)) {
      const input = $("start-form").elements[name];
      if (input && value !== undefined && value !== null) input.placeholder = `${value} (config)`;
    }
    const named = [
      ["compensation", compensation.mode],
      ["procedure", scheduler.procedure],
      ["network", config.model && config.model.network],
      ["duty_cycle", config.arm && config.arm.duty_cycle],
    ];
    for (const [name, value] of named) {
      const select = $("start-form").elements[name];
      if (select && value) select.options[0].textContent = `${value} (config)`;
    }
    $("data-dir").textContent = config.storage ? config.storage.data_dir : "";
  } catch { /* the placeholders are a convenience */ }
}

// "arm" or "two-link", and every list the form offers
export async function loadChoices() {
  let arm = false;
  try { arm = await loadArmModels(); } catch { /* a two-link daemon, or not readable yet */ }
  await Promise.all([loadNetworks(), loadDutyCycles(), loadDefaults()]);
  return arm ? "arm" : "two-link";
}

export function adaptForm(kind) {
  for (const field of document.querySelectorAll("#start-form [data-kind]")) {
    field.hidden = field.dataset.kind !== kind;
  }
  $("run-kind").textContent = kind === "arm" ? "Start an arm run" : "Start a two-link run";
}

// the uncompensated ended runs of this kind: what a run's drift removed is measured against
export function offerReferences(runs, kind) {
  const select = $("reference-select");
  const chosen = select.value;
  const offered = runs.filter((run) => {
    const p = run.parameters || {};
    const arm = Boolean(p.duty_cycle);
    return p.compensation === "off" && FINAL_STATES.includes(run.state)
      && arm === (kind === "arm");
  });
  select.replaceChildren(option("", offered.length ? "(none: only the model's prediction)"
    : "(none yet: run one with compensation off)"));
  for (const run of offered) {
    const p = run.parameters;
    const what = p.duty_cycle || p.procedure || "";
    select.append(option(String(run.id), `run ${run.id}: ${what}, ${run.steps_recorded} steps`));
  }
  if ([...select.options].some((o) => o.value === chosen)) select.value = chosen;
}

export function startBody(form) {
  const body = {};
  for (const [name, value] of new FormData(form)) {
    const input = form.elements[name];
    const label = input.closest("label");
    if (value === "" || (label && label.hidden)) continue;
    body[name] = input.type === "number" || name === "reference_run" ? Number(value) : value;
  }
  return body;
}
