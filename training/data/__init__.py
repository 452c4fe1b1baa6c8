"""Motion data: conversion to the canonical skeleton, the pose representation, the split."""
