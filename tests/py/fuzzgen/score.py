"""Scoring a diagnosis.json against a fuzz session's truth.

Claims are read from the diagnosis' public output only: accepted library hypotheses (by id),
terms found beyond the library (name, fields and the fields of their named ties) and rest-power
terms (field and ties) and the meters' comparison (`discovery.meter_drift`: a change over the
session of one meter's offset or gain relative to the other). Each claim is scored

* right: names an effect's mechanism (a library id of it — an accepted hypothesis, or a found term
  that says which library mechanism it is a form of, `mechanism` in diagnosis.json; or a found term on a field the effect
  follows — and, for a modulated loss term, naming that term; or, for a meter artefact, words of
  a meter/sensor correction);
* located: on an effect's field or naming its loss term, but another mechanism (e.g. a meter
  artefact called a load), or the right term on a proxy of an unrecorded state;
* wrong: none of these while an effect of the session the oracle can see (detectability >=
  `SEEN`) is left unnamed (a wrong story for it);
* spurious: none of these and every visible effect already accounted for (or a null session).

Each effect is named (a right claim), located (a located claim, or a location the diagnosis
prints and does not claim — see `locations`) or missed.
"""


def claims(d):
    """[{kind, id|name, fields}] of a diagnosis (dict of diagnosis.json)."""
    out = [{"kind": "library", "id": h["id"], "name": h.get("title", h["id"]), "fields": []}
           for h in d.get("accepted", [])]
    disc = d.get("discovery") or {}
    for t in disc.get("accepted", []):
        f = list(t.get("fields", []))
        for r in t.get("tied", []):
            f += r.get("fields", [])
        # a found form of a library mechanism (one-sided, switched by a state) names its id
        out.append({"kind": "found", "id": t.get("mechanism"), "name": t.get("name", ""), "fields": f})
    m = disc.get("meter_drift")
    if m:
        out.append({"kind": "meter", "id": None, "name": m.get("name", ""), "fields": []})
    # a sensor window that drifts over the session, claimed as one meter's artefact (the
    # summary's "Meter artefact: the … meter's averaging window drifts")
    for line in d.get("summary", "").splitlines():
        if line.startswith("Meter artefact:"):
            out.append({"kind": "meter", "id": None, "name": line[len("Meter artefact:"):], "fields": []})
    rest = disc.get("rest") or []
    for r in [rest] if isinstance(rest, dict) else rest:  # one rest-power stage: an object
        for t in r.get("found", []):
            out.append({"kind": "rest", "id": None, "name": t.get("name", ""),
                        "fields": [t.get("field", "")] + list(t.get("tied", []))})
    return out


def locations(d):
    """What a diagnosis locates without claiming it, in the form of `claims` (never scored as
    claims): a library form the data support at a size no such mechanism has ("Located: the power
    follows the form of X … outside the physically plausible range"), a library mechanism left
    as "X or Y — mechanism not identified", and found terms the parsimony rule located."""
    out = [{"kind": "library", "id": h["id"], "name": h.get("title", h["id"]), "fields": []}
           for h in d.get("hypotheses", [])
           if h.get("verdict", "").startswith("located")
           or h.get("verdict") == "rejected: parameter outside its physically plausible range"]
    disc = d.get("discovery") or {}
    for t in disc.get("located", []):
        f = list(t.get("fields", [])) + [x for r in t.get("tied", []) for x in r.get("fields", [])]
        out.append({"kind": "found", "id": t.get("mechanism"), "name": t.get("name", ""), "fields": f})
    # rest-power terms the parsimony rule located, and a change of one meter's rest reading the
    # other meter cannot tell from a load (`meter_located`)
    rest = disc.get("rest") or []
    for t in [x for r in ([rest] if isinstance(rest, dict) else rest) for x in r.get("located", [])]:
        out.append({"kind": "rest", "id": None, "name": t.get("name", ""),
                    "fields": [t.get("field", "")] + list(t.get("tied", []))})
    if disc.get("meter_located"):
        m = disc["meter_located"]
        out.append({"kind": "meter", "id": None, "name": m.get("name", ""), "fields": list(m.get("fields", []))})
    # a drifting sensor window the other meter cannot attribute, and a lag the held-out trials
    # cannot tell from a longer window (the summary's "Located: …")
    for line in d.get("summary", "").splitlines():
        if line.startswith("Located:") and "averaging window drifts" in line:
            out.append({"kind": "meter", "id": None, "name": line[len("Located:"):], "fields": []})
        if line.startswith("Located: the readings' timing"):
            out.append({"kind": "library", "id": "latency", "name": line[len("Located:"):], "fields": []})
    return out


def _words(name, words):
    n = name.lower()
    return any(w.lower() in n for w in words)


def relation(c, e):
    """'right', 'located' or None: what claim c says of effect e."""
    x = e["expect"]
    if c["kind"] == "found" and c.get("id") and c["id"] in x["ids"]:
        return "right"
    if c["kind"] == "library":
        if c["id"] in x["ids"]:
            return "right"
        if e["kind"] == "modulated" and _words(c["name"], x["terms"]):
            return "located"
        return None
    on_field = bool(set(c["fields"]) & set(x["fields"]))
    names_term = bool(x["terms"]) and _words(c["name"], x["terms"])
    if e["kind"] == "meter":
        if _words(c["name"], x["meter_words"]) and not x.get("ids") and _meter_named(c["name"]) in (None, x.get("meter")):
            return "right"
        return "located" if on_field else None
    if e["kind"] == "modulated":
        if on_field and names_term:
            return "right"
        return "located" if (on_field or names_term) else None
    if e["kind"] == "load":
        if on_field:
            return "located" if any(_words(c["name"], w) for w in _TERM_WORDS) else "right"
        return None
    # library mechanism: a found term that names its loss term is located
    return "located" if (on_field or names_term) else None


def _meter_named(name):
    """The meter a claim is about: the first of main board ("mbs") or battery ("bms") it names."""
    n = name.lower()
    at = {m: n.find(w) for m, w in (("mbs", "main-board"), ("bms", "battery")) if w in n}
    return min(at, key=at.get) if at else None


_TERM_WORDS = [["copper", "τ²"], ["coulomb", "|q̇|"], ["viscous", "q̇²"], ["transmitted", "efficien"]]


SEEN = 0.01  # held-out RMSE gain below which an effect cannot be what a claim is about


def score(truth_effects, detect, claim_list, gate=SEEN, located=()):
    """Score claims and effects. truth_effects: the drawn effects; detect: oracle gain per effect;
    located: the diagnosis' `locations` (they can only make a missed effect located)."""
    rel = [[relation(c, e) for e in truth_effects] for c in claim_list]
    eff_state = ["missed"] * len(truth_effects)
    claim_state = [None] * len(claim_list)
    # A claim that fits two drawn effects (two forms of one mechanism) is about the one the data
    # show most: the first in the drawn order could be an effect below detection (seed 14146035).
    by_gain = sorted(range(len(truth_effects)), key=lambda i: -detect[i])
    for want in ("right", "located"):
        for ci in range(len(claim_list)):
            if claim_state[ci] is not None:
                continue
            for ei in by_gain:
                if rel[ci][ei] == want and eff_state[ei] == "missed":
                    claim_state[ci] = want
                    eff_state[ei] = "named" if want == "right" else "located"
                    break
    for ei, e in enumerate(truth_effects):
        if eff_state[ei] == "missed" and any(relation(c, e) for c in located):
            eff_state[ei] = "located"
    # Lags of one meter (a sensor latency and a meter lag on the main board, or two of either)
    # add up to one delay: the claim or location of it is about each of them (seed 948288070
    # drew 0.494 s and 0.017 s; one latency of 0.51 s is all the readings can show).
    delay = lambda e: e["expect"].get("ids") == ["latency"] and e.get("meter", "mbs") == "mbs"
    delays = [ei for ei, e in enumerate(truth_effects) if delay(e)]
    best = "named" if any(eff_state[ei] == "named" for ei in delays) else \
        "located" if any(eff_state[ei] == "located" for ei in delays) else "missed"
    for ei in delays:
        eff_state[ei] = best
    # a second claim of an effect already named counts as spurious (one mechanism, one claim)
    unnamed = [ei for ei in range(len(truth_effects)) if eff_state[ei] == "missed" and detect[ei] >= gate]
    for ci in range(len(claim_list)):
        if claim_state[ci] is None:
            claim_state[ci] = "wrong" if unnamed else "spurious"
    return claim_state, eff_state
