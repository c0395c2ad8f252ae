// The run form adapts to the kind of run this daemon starts (its view, GET /kinds): the
// fields only that kind asks for, its title, and the uncompensated reference runs when
// references apply to it. Every kind: compensation, duration, step and time scale. Empty
// fields take the configured value, shown as the placeholder.
import { api } from "./api.js";
import { fill, viewOf } from "./kinds.js";
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
  try {
    const list = await api("GET", "/arm-models");
    for (const model of list.arm_models || []) {
      const fit = model.marker_rms_um === null
        ? "" : `, fit RMS ${model.marker_rms_um.toFixed(2)} µm`;
      $("arm-model-select").append(option(model.name,
        `${model.name} (identified from ${model.source_runs.join(", ")})`,
        `arm ${model.arm}, duty cycle ${model.duty_cycle}, identified ${model.identified_at}`
          + fit));
    }
  } catch { /* the list is a convenience; the preset arm is the default */ }
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

// every list the form offers
export async function loadChoices() {
  await Promise.all([loadArmModels(), loadNetworks(), loadDutyCycles(), loadDefaults()]);
}

// the form of the kind this daemon starts (null: its view is not known yet, the form stays
// as it is)
export function adaptForm(view) {
  if (!view) return;
  for (const field of document.querySelectorAll("#start-form [data-field]")) {
    field.hidden = !view.form_fields.includes(field.dataset.field);
  }
  $("reference-field").hidden = !view.reference_runs;
  $("run-kind").textContent = view.form_title;
}

// the uncompensated ended runs a run of this view may name as its reference: what its drift
// removed is measured against
export function offerReferences(runs, view) {
  if (!view || !view.reference_runs) return;
  const select = $("reference-select");
  const chosen = select.value;
  const offered = runs.filter((run) => {
    const p = run.parameters || {};
    return p.compensation === "off" && FINAL_STATES.includes(run.state)
      && view.reference_kinds.includes(run.kind);
  });
  select.replaceChildren(option("", offered.length ? "(none: only the model's prediction)"
    : "(none yet: run one with compensation off)"));
  for (const run of offered) {
    const what = fill(viewOf(run).reference_text, run.parameters);
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
