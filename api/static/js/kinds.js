// The run kinds' views (GET /api/v1/kinds; daemon/run/kind.py KindView): each kind says which
// plots its runs draw, what its start form asks for, how the runs table and the headline
// describe its runs and which runs may be its reference. The page renders from them and names
// no kind (tests/test_kind_isolation.py): a new kind brings its own view.
import { api } from "./api.js";

export const kinds = {
  views: new Map(), // name -> view
  started: null, // the kind a start from the configured parameters makes
  loaded: false,
};

// false while the views cannot be read yet (a refused token: the poll tries again)
export async function loadKinds() {
  try {
    const list = await api("GET", "/kinds");
    kinds.views = new Map(list.kinds.map((view) => [view.name, view]));
    kinds.started = list.default;
    kinds.loaded = true;
  } catch { /* the caller tries again */ }
  return kinds.loaded;
}

// the view of a run's kind (its record's kind), null when it is not known: a run recorded
// before runs said their kind, or of a kind this daemon does not know
export function viewOf(run) {
  return (run && kinds.views.get(run.kind)) || null;
}

// the view of what this daemon starts: the start form's
export function startedView() {
  return kinds.views.get(kinds.started) || null;
}

// A view's template with the run's parameters: "{name}" is parameter name; a template that
// names a parameter the run left unset gives "".
export function fill(template, parameters) {
  if (!template) return "";
  const p = parameters || {};
  let unset = false;
  const text = template.replace(/\{(\w+)\}/g, (_, name) => {
    const value = p[name];
    if (value === null || value === undefined || value === "") unset = true;
    return String(value);
  });
  return unset ? "" : text;
}
