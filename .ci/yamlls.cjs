// Ask yaml-language-server's language service (pinned in .ci/run) what an editor shows: the diagnostics of a YAML
// buffer and the completions at positions in it, with the settings VS Code's YAML extension starts with.  A buffer
// is known by its file's path, as an editor knows it, so a `# yaml-language-server: $schema=...` modeline resolves
// against the file's folder and the schema is read from disk; no other schema source is configured (no network).
// usage: node .ci/yamlls.cjs REQUESTS.json
// REQUESTS: [{"file": PATH, "text": TEXT (default: the file's), "complete": [[LINE, CHARACTER], ...]}], 0-based.
// prints [{"file", "diagnostics": [{"line", "character", "severity", "message"}], "completions": [[{"label",
// "insertText", "kind"}, ...] per position]}] as JSON.
const { readFileSync } = require("node:fs");
const { pathToFileURL, fileURLToPath } = require("node:url");
const { getLanguageService } = require("yaml-language-server/lib/umd/languageservice/yamlLanguageService");
const { workspaceContext } = require("yaml-language-server/lib/umd/languageservice/services/schemaRequestHandler");
const { TextDocument } = require("vscode-languageserver-textdocument");

async function readSchema(uri) {
  if (!uri.startsWith("file:")) throw new Error(`${uri}: only local schemas are read here`);
  return readFileSync(fileURLToPath(uri), "utf8");
}

async function main() {
  const requests = JSON.parse(readFileSync(process.argv[2], "utf8"));
  const service = getLanguageService({ schemaRequestService: readSchema, workspaceContext });
  // VS Code's YAML extension's defaults (yaml.validate, yaml.completion, yaml.hover: true; YAML 1.2)
  service.configure({ validate: true, completion: true, hover: true, format: true, yamlVersion: "1.2", schemas: [] });
  const answers = [];
  for (const [version, request] of requests.entries()) {
    const text = request.text ?? readFileSync(request.file, "utf8");
    const document = TextDocument.create(pathToFileURL(request.file).toString(), "yaml", version, text);
    const diagnostics = (await service.doValidation(document, false)).map((d) => ({
      line: d.range.start.line,
      character: d.range.start.character,
      severity: d.severity,
      message: d.message,
    }));
    const completions = [];
    for (const [line, character] of request.complete ?? []) {
      const list = await service.doComplete(document, { line, character }, false);
      completions.push(list.items.map((i) => ({ label: i.label, insertText: i.insertText ?? i.textEdit?.newText ?? i.label, kind: i.kind })));
    }
    answers.push({ file: request.file, diagnostics, completions });
  }
  process.stdout.write(JSON.stringify(answers, null, 1) + "\n");
}

main().catch((err) => {
  process.stderr.write(`${err.stack || err}\n`);
  process.exit(2);
});
