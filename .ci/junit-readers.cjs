// Read a JUnit XML file as two GitHub test-report actions read it, with their own XML parsers (installed by .ci/run):
//   mikepenz/action-junit-report: xml-js's xml2json(data, {compact: true}), a test case's `_attributes`;
//   dorny/test-reporter (its phpunit-junit reader): xml2js's parseStringPromise(data), a test case's `$`.
// usage: node .ci/junit-readers.cjs FILE   prints {"xml-js": [CASE...], "xml2js": [CASE...]},
// CASE = {name, classname, file, line, failed} as each reads it (absent attributes are null).
const { readFileSync } = require("node:fs");
const convert = require("xml-js");
const { parseStringPromise } = require("xml2js");

const list = (x) => (x === undefined ? [] : Array.isArray(x) ? x : [x]);

function xmljs(data) {
  const report = JSON.parse(convert.xml2json(data, { compact: true }));
  const cases = [];
  const walk = (suite) => {
    for (const s of list(suite)) {
      walk(s.testsuite);
      for (const c of list(s.testcase)) {
        const a = c._attributes || {};
        cases.push({ name: a.name, classname: a.classname ?? null, file: a.file ?? null, line: a.line ?? null, failed: "failure" in c });
      }
    }
  };
  walk(report.testsuites ? report.testsuites : report.testsuite);
  return cases;
}

async function xml2js(data) {
  const report = await parseStringPromise(data);
  const cases = [];
  const walk = (suites) => {
    for (const s of suites || []) {
      walk(s.testsuite);
      for (const c of s.testcase || []) {
        const a = c.$ || {};
        cases.push({ name: a.name, classname: a.classname ?? null, file: a.file ?? null, line: a.line ?? null, failed: "failure" in c });
      }
    }
  };
  walk(report.testsuites.testsuite);
  return cases;
}

(async () => {
  const data = readFileSync(process.argv[2], "utf8");
  process.stdout.write(JSON.stringify({ "xml-js": xmljs(data), xml2js: await xml2js(data) }) + "\n");
})();
