// A small stand-in of Flamenco 3's job compiler API (author.Task, author.Command, job.addTask,
// task.addDependency),
// enough to run a custom job type's compileJob with node: tests/blender/test_farm_exports.py.
// The job type runs in a bare context (no require, no process, no Node globals), as in the
// Manager's JavaScript engine. Usage: node flamenco_standin.js JOB_TYPE.js SUBMISSION.json
// prints {"job_type": ..., "tasks": [{name, type, commands: [{type, parameters}], dependencies: [names]}]}.
"use strict";
const fs = require("fs");
const vm = require("vm");

const [jobTypeFile, submissionFile] = process.argv.slice(2);
const submission = JSON.parse(fs.readFileSync(submissionFile, "utf8"));

const author = {
  Task(name, type) {
    return { name, type, commands: [], dependencies: [], addCommand(cmd) { this.commands.push(cmd); },
      addDependency(task) { this.dependencies.push(task.name); } };
  },
  Command(type, parameters) {
    return { type, parameters };
  },
};
const tasks = [];
const job = { name: submission.name, settings: submission.settings, metadata: submission.metadata || {},
  addTask(task) { tasks.push(task); } };

const context = vm.createContext({ author, print: () => {} });
vm.runInContext(fs.readFileSync(jobTypeFile, "utf8"), context, { filename: jobTypeFile });
vm.runInContext("this.__jobType = JOB_TYPE;", context);
context.compileJob(job);
process.stdout.write(JSON.stringify({ job_type: context.__jobType,
  tasks: tasks.map((t) => ({ name: t.name, type: t.type, commands: t.commands, dependencies: t.dependencies })) }));
