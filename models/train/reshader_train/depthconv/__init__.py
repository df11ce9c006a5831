"""Conversion of the shipped Tiefenrausch depth network (Caffe2 int8 NetDef) to ONNX.

protobuf: a small wire-format reader for the Caffe2 NetDef subset; caffe2_model: the int8
graph as data; onnx_export: int8 (QLinearConv or QDQ) and fp32 ONNX graphs; preprocess: the
model's input convention; verify: errors against the original implementation's output;
command: the `convert-depth` subcommand.
"""
