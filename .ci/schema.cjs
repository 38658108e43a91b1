// Validate files against a JSON Schema as an editor does: YAML read by `yaml` (the parser yaml-language-server
// uses; YAML 1.2, unique keys), checked by ajv (pinned in .ci/run) in the schema's own draft, strict mode.
// usage: node .ci/schema.cjs SCHEMA.json FILE...
// prints one JSON object {file: {verdict, errors}}; verdict is "accept", "reject" (the schema refuses the data)
// or "unparsed" (the YAML parser refuses the text). A schema ajv cannot compile exits 2 with its message.
const { readFileSync } = require("node:fs");
const YAML = require("yaml");

const DRAFTS = {
  "https://json-schema.org/draft/2020-12/schema": "ajv/dist/2020",
  "https://json-schema.org/draft/2019-09/schema": "ajv/dist/2019",
  "http://json-schema.org/draft-07/schema#": "ajv",
};

const [schemaPath, ...files] = process.argv.slice(2);
const schema = JSON.parse(readFileSync(schemaPath, "utf8"));
const Ajv = require(DRAFTS[schema.$schema] || "ajv").default;
let validate;
try {
  // strict: unknown keywords, ignored types, unmatched tuples and non-finite numbers are errors, as an editor's
  // validator would have to treat them; patterns are compiled with the `u` flag, as yaml-language-server does.
  const ajv = new Ajv({ strict: true, allErrors: true, allowUnionTypes: true });
  // the keywords editors read beside JSON Schema's (yaml-language-server, VS Code): annotations to a validator
  ajv.addVocabulary(["defaultSnippets", "markdownDescription", "patternErrorMessage", "errorMessage"]);
  validate = ajv.compile(schema);
} catch (err) {
  process.stderr.write(`ajv cannot compile ${schemaPath}: ${err.message}\n`);
  process.exit(2);
}

const verdicts = {};
for (const file of files) {
  const text = readFileSync(file, "utf8");
  let data;
  try {
    const doc = YAML.parseDocument(text, { uniqueKeys: true, merge: true });
    if (doc.errors.length) throw doc.errors[0];
    data = file.endsWith(".json") ? JSON.parse(text) : doc.toJS({ maxAliasCount: 100 });
  } catch (err) {
    verdicts[file] = { verdict: "unparsed", errors: [String(err.message).split("\n")[0]] };
    continue;
  }
  const ok = validate(data);
  verdicts[file] = {
    verdict: ok ? "accept" : "reject",
    errors: ok ? [] : validate.errors.map((e) => `${e.instancePath || "/"} ${e.message}`),
  };
}
process.stdout.write(JSON.stringify(verdicts, null, 1) + "\n");
